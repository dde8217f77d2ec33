"""``rtsid watch --web [PORT]``: one live page per lab, served on 127.0.0.1, no install.

::

    daemons ──zenoh (router or peers)──► LabFeed ──"rtsid-web-feed" thread──► LabBoard
                                                                             │ (last 30 s per
    browser ◄── GET / , /static/… (page, uPlot shipped as package data)      │  robot/joint)
            ◄── GET /events  (Server-Sent Events: snapshot, then each        ◄┘
                              estimate, status, alive, gone as it arrives)

The page (``static/index.html`` + ``app.js``) draws, for each ``robot/joint``: the tracked
stiffness K_track with its 95 % band and the window's K beside it, B and I with their 95 % bands
(held values as held, no band) over the last 30 s, VAF, withheld windows with their reason, and
the link and deadline counters of the status message; the latest message of any other channel a
daemon publishes (e.g. a reflex model) is shown as its fields, so a new channel needs no change
here.
On start the board asks the daemons for their last 30 s (the ``history`` queryable), so the
plots are full at once. Everything is standard library (``http.server``) and the plotting
library (uPlot, MIT) ships inside the package: labs are often offline.

Nothing binds beyond loopback unless ``host`` says so (``--host 0.0.0.0`` opens the page to
the lab network), and then only with a token (``RTSID_WEB_TOKEN``, :mod:`rtsid.io.access_token`)
checked on every request: refused without one.

The page renders data, never markup: the server relays only messages that pass
:mod:`rtsid.io.validate` (names of letters, digits, ``_ . -`` equal to the key they came on;
finite numbers within bounds; capped sizes; reasons and flags from their closed vocabularies),
counts the rest (``rejected`` on the page: "rejected N malformed messages") and serves every
response with :data:`SECURITY_HEADERS`: a Content-Security-Policy that allows scripts, styles
and connections from this origin only (no inline script, no framing), ``nosniff`` and no
referrer. The page itself puts message fields in with ``textContent`` only.
"""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from http import HTTPStatus
from http.cookies import CookieError, SimpleCookie
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs

from rtsid.errors import ConfigError, ServiceError
from rtsid.io.access_token import TOKEN_ENV, token_matches, web_token
from rtsid.io.validate import (
    NAME_PATTERN,
    MalformedMessage,
    decode_message,
    joint_of_key,
    printable,
)
from rtsid.io.watch import FeedEvent, LabFeed, window_ms

__all__ = ["SECURITY_HEADERS", "LabBoard", "WebView", "serve_web"]

log = logging.getLogger(__name__)

#: Seconds of estimates the page plots (and the board keeps per joint).
WINDOW_S = 30.0
_MAX_RATE_HZ = 200.0  # bound on estimates per joint kept for WINDOW_S (worker hop ≥ 5 ms)
_EVENTS_KEPT = 4096  # events a slow page may fall behind by before it gets a fresh snapshot
_CONTENT_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".txt": "text/plain; charset=utf-8",
    ".LICENSE": "text/plain; charset=utf-8",
}
_ESTIMATE_KEYS = (
    "seq", "K_track", "K_track_se", "K", "K_se", "B", "B_se", "B_held", "I", "I_se", "I_held",
    "vaf", "ok", "reason", "flags", "latency_ms",
)  # fmt: skip
#: Sent with every response: this origin's scripts, styles and connections only (no inline
#: script, no eval, no plugins), never framed, no MIME sniffing, no referrer.
SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; "
        "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
    "Cross-Origin-Resource-Policy": "same-origin",
}
#: Files the page is made of (nothing else under /static/ is served).
_STATIC_FILES = frozenset(
    f.name for f in (resources.files("rtsid.io.web") / "static").iterdir() if f.is_file()
)


def _point(message: dict[str, Any]) -> dict[str, Any]:
    """What the page needs of a checked estimate (t: publication time, UNIX s; window_ms: the
    window's length, for "K (300 ms window)")."""
    point = {k: message.get(k) for k in _ESTIMATE_KEYS}
    point["t"] = message["host_time_ns"] / 1e9
    point["window_ms"] = window_ms(message)
    return point


class LabBoard:
    """The last :data:`WINDOW_S` of estimates and the latest status of every ``robot/joint``,
    and the numbered event stream the pages follow (thread-safe; one writer: the feed)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._joints: dict[str, dict[str, Any]] = {}
        self._events: deque[tuple[int, str]] = deque(maxlen=_EVENTS_KEPT)
        self._next_id = 1
        self.notes: deque[str] = deque(maxlen=10)
        self._gone_names: set[str] = set()  # left (token gone), until their token is back
        self.stopped = False
        #: Messages refused (malformed, non-finite, oversized, another daemon's name).
        self.rejected = 0
        self.last_rejection: str | None = None

    # ------------------------------------------------------------------ writer side
    def take(self, event: FeedEvent) -> None:
        """Add one feed event (estimate, status, any other channel, alive, gone); one that
        fails the checks of :mod:`rtsid.io.validate` is counted in :attr:`rejected` and the
        pages are told the count."""
        try:
            if not NAME_PATTERN.match(event.kind):
                raise MalformedMessage(f"channel {printable(repr(event.kind), 80)} is not a name")
            if event.kind in ("alive", "gone"):
                self._liveliness(joint_of_key(event.key), event.kind == "alive")
                return
            message = decode_message(event.kind, event.payload, event.key)
        except MalformedMessage as exc:
            self.reject(f"{printable(event.key, 120)}: {exc}")
            return
        self._take(event.kind, message)

    def reject(self, why: str) -> None:
        """Count one refused message and tell the pages."""
        with self._cond:
            self.rejected += 1
            self.last_rejection = why
            self._emit({"type": "rejected", "count": self.rejected, "last": why})

    def _take(self, kind: str, message: dict[str, Any]) -> None:
        name = f"{message['robot']}/{message['joint']}"
        with self._cond:
            joint = self._joints.get(name)
            if joint is None:
                if name in self._gone_names:
                    return  # late messages of a daemon that left
                joint = self._joints[name] = self._new_joint()
            if kind == "status":
                joint["status"] = message
                self._emit({"type": "status", "joint": name, "status": message})
                return
            if kind != "estimate":  # any other channel a daemon publishes: its latest
                joint["channels"][kind] = message
                self._emit({"type": "channel", "joint": name, "channel": kind, "message": message})
                return
            point = _point(message)
            points = joint["points"]
            if points and point["seq"] is not None and points[-1]["seq"] is not None:
                if point["seq"] <= points[-1]["seq"] and point["t"] <= points[-1]["t"]:
                    return  # already held (history and live overlap)
            points.append(point)
            self._trim(points, point["t"])
            self._emit({"type": "estimate", "joint": name, "point": point})

    def _liveliness(self, name: str, alive: bool) -> None:
        with self._cond:
            if alive:
                self._gone_names.discard(name)
                self._emit({"type": "alive", "joint": name})
                return
            self._gone_names.add(name)
            if self._joints.pop(name, None) is not None:
                note = f"{name} left at {time.strftime('%H:%M:%S')} (liveliness token gone)"
                self.notes.append(note)
                self._emit({"type": "gone", "joint": name, "note": note})

    @staticmethod
    def _new_joint() -> dict[str, Any]:
        return {
            "points": deque(maxlen=int(WINDOW_S * _MAX_RATE_HZ)),
            "status": None,
            "channels": {},
        }

    @staticmethod
    def _trim(points: deque[dict[str, Any]], newest_t: float) -> None:
        while points and points[0]["t"] < newest_t - WINDOW_S:
            points.popleft()

    def _emit(self, event: dict[str, Any]) -> None:
        """Number and keep one event, wake the pages (caller holds the condition)."""
        self._events.append((self._next_id, json.dumps(event, allow_nan=False)))
        self._next_id += 1
        self._cond.notify_all()

    def stop(self) -> None:
        """Wake every page stream so it ends."""
        with self._cond:
            self.stopped = True
            self._cond.notify_all()

    # ------------------------------------------------------------------ reader side
    def snapshot(self) -> tuple[int, dict[str, Any]]:
        """(id of the newest event included, the whole board as plain data)."""
        with self._cond:
            joints = {
                name: {
                    "points": list(j["points"]),
                    "status": j["status"],
                    "channels": dict(j["channels"]),
                }
                for name, j in sorted(self._joints.items())
            }
            return self._next_id - 1, {
                "type": "snapshot",
                "window_s": WINDOW_S,
                "joints": joints,
                "notes": list(self.notes),
                "rejected": self.rejected,
                "last_rejection": self.last_rejection,
            }

    def events_after(self, last_id: int, timeout_s: float) -> list[tuple[int, str]] | None:
        """Events newer than ``last_id`` (waiting up to ``timeout_s`` for one); None when the
        page fell further behind than the events kept (it must take a fresh snapshot)."""
        with self._cond:
            if not self.stopped and (not self._events or self._events[-1][0] <= last_id):
                self._cond.wait(timeout_s)
            if self._events and self._events[0][0] > last_id + 1:
                return None
            return [(i, e) for i, e in self._events if i > last_id]


def _static(name: str) -> bytes | None:
    """A file of the page (package data), or None when there is no such file."""
    if name not in _STATIC_FILES:
        return None
    return (resources.files("rtsid.io.web") / "static" / name).read_bytes()


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("web: " + format, *args)

    _COOKIE = "rtsid_token"

    def _presented_token(self) -> tuple[str | None, bool]:
        """The token this request carries, and whether it came in the URL."""
        auth = self.headers.get("Authorization", "")
        if auth.startswith("Bearer "):
            return auth.removeprefix("Bearer "), False
        in_url = parse_qs(self.path.partition("?")[2]).get("token")
        if in_url:
            return in_url[0], True
        try:
            cookie = SimpleCookie(self.headers.get("Cookie", ""))
        except CookieError:
            return None, False
        morsel = cookie.get(self._COOKIE)
        return (morsel.value if morsel is not None else None), False

    def _authorized(self) -> bool:
        """Loopback without a token: everyone here; otherwise the token, constant-time."""
        self._new_cookie: str | None = None
        expected = self.server.token
        if expected is None:
            return True
        given, in_url = self._presented_token()
        if token_matches(given, expected):
            if in_url:  # the page's own requests (scripts, /events) then carry the cookie
                self._new_cookie = f"{self._COOKIE}={expected}; HttpOnly; SameSite=Strict; Path=/"
            return True
        body = f"this page needs its token: open /?token=<the {TOKEN_ENV} value>\n".encode()
        self._send(HTTPStatus.UNAUTHORIZED, "text/plain; charset=utf-8", body)
        return False

    def end_headers(self) -> None:
        """Every response: :data:`SECURITY_HEADERS`, and the token's cookie once it was given
        in the URL."""
        for name, value in SECURITY_HEADERS.items():
            self.send_header(name, value)
        if getattr(self, "_new_cookie", None):
            self.send_header("Set-Cookie", str(self._new_cookie))
        super().end_headers()

    def do_GET(self) -> None:
        if not self._authorized():
            return
        path = self.path.split("?", 1)[0]
        if path in ("/", "/index.html"):
            self._file("index.html")
        elif path.startswith("/static/"):
            self._file(path.removeprefix("/static/"))
        elif path == "/state.json":
            _, snap = self.server.board.snapshot()
            body = json.dumps(snap, allow_nan=False).encode()
            self._send(HTTPStatus.OK, "application/json", body)
        elif path == "/events":
            self._events()
        else:
            self._send(HTTPStatus.NOT_FOUND, "text/plain", b"not found\n")

    def _file(self, name: str) -> None:
        data = _static(name)
        if data is None:
            self._send(HTTPStatus.NOT_FOUND, "text/plain", b"not found\n")
            return
        suffix = "." + name.rsplit(".", 1)[-1]
        self._send(HTTPStatus.OK, _CONTENT_TYPES.get(suffix, "application/octet-stream"), data)

    def _send(self, status: HTTPStatus, content_type: str, body: bytes) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _events(self) -> None:
        """Server-Sent Events: a snapshot, then every event; a keep-alive comment each 5 s."""
        board = self.server.board
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        try:
            for chunk in self._stream(board):
                self.wfile.write(chunk)
                self.wfile.flush()
        except (BrokenPipeError, ConnectionResetError):
            return  # the page went away

    def _stream(self, board: LabBoard) -> Iterator[bytes]:
        last_id, snap = board.snapshot()
        yield b"data: " + json.dumps(snap, allow_nan=False).encode() + b"\n\n"
        quiet_since = time.monotonic()
        while not board.stopped and not self.server.stopping.is_set():
            events = board.events_after(last_id, 0.5)
            if events is None:  # fell behind: start again from a snapshot
                last_id, snap = board.snapshot()
                yield b"data: " + json.dumps(snap, allow_nan=False).encode() + b"\n\n"
                continue
            if events:
                last_id = events[-1][0]
                yield b"".join(b"data: " + e.encode() + b"\n\n" for _, e in events)
                quiet_since = time.monotonic()
            elif time.monotonic() - quiet_since > 5.0:
                yield b": keep-alive\n\n"
                quiet_since = time.monotonic()


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = True  # server_close() joins the page threads (they end within 0.5 s)

    def __init__(self, address: tuple[str, int], board: LabBoard, token: str | None) -> None:
        self.board = board
        self.token = token
        self.stopping = threading.Event()
        super().__init__(address, _Handler)

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A page or client that broke its connection: a debug line, never a traceback on
        the console (socketserver's default prints one)."""
        log.debug("web: request from %s ended: %r", client_address, sys.exc_info()[1])


class WebView:
    """The page server and the zenoh feed behind it (a context manager with a bounded stop).

    Parameters
    ----------
    key : str
        Daemons' key expression, e.g. ``rtsid/*/*``.
    connect : tuple of str
        A router's endpoint, or the daemons' (peer to peer).
    mode : str
        ``"client"`` through a router, ``"peer"`` straight to daemons.
    host : str
        Address the page binds to (default 127.0.0.1). Beyond loopback the page requires the
        token in ``RTSID_WEB_TOKEN`` (a :class:`~rtsid.errors.ConfigError` without one).
    port : int
        TCP port (0: a free one; :attr:`port` says which).
    history_s : float
        Seconds of history asked from the daemons on start (0: none).
    """

    def __init__(
        self,
        key: str,
        connect: tuple[str, ...],
        *,
        mode: str = "peer",
        host: str = "127.0.0.1",
        port: int = 8088,
        history_s: float = WINDOW_S,
    ) -> None:
        if not 0 <= port <= 65535:
            raise ConfigError(f"--web port {port} is not accepted; expected 0…65535")
        self.key = key.rstrip("/")
        self.connect = connect
        self.mode = mode
        self.host = host
        self.requested_port = port
        self.history_s = history_s
        self.token = web_token(host)  # None on loopback without RTSID_WEB_TOKEN
        self.board = LabBoard()
        self.port: int | None = None
        self.failure: str | None = None
        self._server: _Server | None = None
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self._feed_ready = threading.Event()

    @property
    def url(self) -> str:
        """The page's address."""
        return f"http://{self.host}:{self.port}/"

    def start(self) -> WebView:
        """Bind the page, start the feed; returns once the feed is subscribed.

        Raises
        ------
        ServiceError
            The port is taken or the address cannot be bound, or the feed could not open.
        """
        try:
            self._server = _Server((self.host, self.requested_port), self.board, self.token)
        except OSError as exc:
            raise ServiceError(
                f"web page on {self.host}:{self.requested_port} could not bind: {exc}; choose a "
                "free port with --web PORT"
            ) from None
        self.port = int(self._server.server_address[1])
        feed = threading.Thread(target=self._feed_loop, name="rtsid-web-feed", daemon=True)
        http = threading.Thread(
            target=self._server.serve_forever, kwargs={"poll_interval": 0.2}, name="rtsid-web-http"
        )
        self._threads = [feed, http]
        feed.start()
        http.start()
        self._feed_ready.wait(30.0)
        if self.failure is not None:
            self.stop()
            raise ServiceError(self.failure)
        return self

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Stop the feed, end the page streams and close the server; True if all ended."""
        self._stop.set()
        self.board.stop()
        server, self._server = self._server, None
        if server is not None:
            server.stopping.set()
            server.shutdown()
            server.server_close()
        for thread in self._threads:
            thread.join(timeout_s)
        return not any(t.is_alive() for t in self._threads)

    def __enter__(self) -> WebView:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _feed_loop(self) -> None:
        try:
            with LabFeed(self.key, self.connect, self.mode) as feed:
                self._feed_ready.set()
                for event in feed.session().events:  # subject/condition, however old
                    self.board.take(event)
                if self.history_s > 0:
                    past = feed.history(self.history_s)
                    for note in past.notes:
                        log.info("%s", note)
                    for why in past.rejected:
                        self.board.reject(why)
                    for event in past.events:
                        self.board.take(event)
                while not self._stop.is_set():
                    events = feed.poll()
                    for event in events:
                        self.board.take(event)
                    if not events:
                        self._stop.wait(0.002)
        except Exception as exc:  # a feed that cannot open or breaks is reported, not hidden
            self.failure = f"web view's zenoh feed via {', '.join(self.connect)} failed: {exc}"
            log.error("%s", self.failure)
        finally:
            self._feed_ready.set()


def serve_web(
    key: str,
    connect: tuple[str, ...],
    *,
    mode: str = "peer",
    host: str = "127.0.0.1",
    port: int = 8088,
    timeout_s: float | None = None,
) -> int:
    """``rtsid watch --web``: serve the page until Ctrl-C (or ``timeout_s``); 1 if the feed
    failed while running."""
    with WebView(key, connect, mode=mode, host=host, port=port) as view:
        print(
            f"rtsid watch: live page on {view.url} (daemons {view.key} via "
            f"{', '.join(connect)}, {mode})"
            + (f"; token required: open it as {view.url}?token=<{TOKEN_ENV}>" if view.token else "")
            + "; Ctrl-C stops",
            flush=True,
        )
        end = None if timeout_s is None else time.monotonic() + timeout_s
        try:
            while view.failure is None and (end is None or time.monotonic() < end):
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
    if view.failure is not None:
        raise ServiceError(view.failure)
    return 0
