"""Publishing over Eclipse Zenoh: estimates, status, samples, liveliness and queryables.

Key expressions (``<prefix>`` defaults to ``rtsid``)::

    <prefix>/<robot>/<joint>/estimate   JSON, one message per window (express, drop when congested)
    <prefix>/<robot>/<joint>/status     JSON, 1–2 Hz
    <prefix>/<robot>/<joint>/samples    JSON batches of raw samples (when publish_samples is on)
    <prefix>/<robot>/<joint>/reflex     JSON, one message per slow-lane fit (when [slow_lane] is on)
    <prefix>/<robot>/<joint>/alive      liveliness token while the daemon runs
    <prefix>/<robot>/<joint>/config     queryable: the daemon's configuration (JSON)
    <prefix>/<robot>/<joint>/estimate   queryable: the latest estimate (a late joiner's first value)
    <prefix>/<robot>/<joint>/status     queryable: the latest status (JSON)
    <prefix>/<robot>/<joint>/history    queryable: estimates and status over the last
                                        ``history_s`` (parameters in :mod:`rtsid.io.history`)
    <prefix>/<robot>/<joint>/session    JSON SessionMessage at start and on a condition change;
                                        queryable: the current one (late joiners)
    <prefix>/<robot>/<joint>/marker     JSON MarkerMessage, each marker as recorded
    <prefix>/<robot>/<joint>/mark       queryable: record a marker on the next sample, reply
                                        when it is in the MCAP file (``rtsid mark``)
    <prefix>/<robot>/<joint>/mark/in    subscriber: a put records a marker (no acknowledgement)
    <prefix>/<robot>/<joint>/condition  queryable: change the condition (``rtsid condition``)

Marker and condition requests go into a bounded :class:`RequestInbox` (the callbacks never
block); the daemon's session desk (:mod:`rtsid.runtime.session`) takes them from there.

The default session is a peer listening on ``tcp/127.0.0.1:7447`` with multicast and gossip
scouting off, so any zenoh client on this machine connects there; a lab names endpoints or a
router in ``[zenoh]`` (``mode = "client"``, ``connect = [the router]``), or hands over a whole
zenoh json5 file (``config_file``). :func:`router_config` builds the configuration of
``rtsid router`` (eclipse-zenoh's own router mode, loopback by default).

:class:`ZenohPublisher` never raises into its caller: when the session cannot open (port
taken, bad endpoint) the error is logged, counted and kept in :meth:`~ZenohPublisher.stats`,
publishing is skipped (counted as ``not_published``), and a background thread retries the
session every ``retry_interval_s``. A client whose router is gone (zenoh reconnects by
itself) has nowhere to send: its messages are counted as ``not_published`` too, never as
``published``. Queryable callbacks only reply with a prepared bytes
snapshot; they never call into the session nor block.
"""

from __future__ import annotations

import json
import logging
import os
import re
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rtsid.config import invalid, section_from_mapping
from rtsid.errors import ConfigError
from rtsid.io.history import HistoryStore, QueryError, parse_history_query
from rtsid.io.schemas import encode_estimate, encode_json, encode_samples, encode_status
from rtsid.io.zenoh_config import ENDPOINT_PATTERN, ZenohConfig

__all__ = [
    "VIEWER_CONFIG_ENV",
    "QueryAnswer",
    "Request",
    "RequestInbox",
    "RouterConfig",
    "ZenohConfig",
    "ZenohPublisher",
    "key_expressions",
    "open_when_reachable",
    "query",
    "router_config",
    "subscriber_config",
    "user_key_expr",
    "zenoh_config",
]

log = logging.getLogger("rtsid.io.zenoh")

#: Why a message was not published (``not_published_by_reason`` in the status).
NOT_PUBLISHED_REASONS = ("session_down", "no_router")

_KEYS = (
    "estimate",
    "status",
    "samples",
    "reflex",
    "alive",
    "config",
    "history",
    "session",
    "marker",
    "mark",
    "condition",
)


def key_expressions(cfg: ZenohConfig) -> dict[str, str]:
    """The key expressions of one daemon: estimate, status, samples, reflex, alive, config,
    history, session, marker, mark, condition, and ``mark_in`` (``…/mark/in``)."""
    base = f"{cfg.key_prefix}/{cfg.robot}/{cfg.joint}"
    keys = {name: f"{base}/{name}" for name in _KEYS}
    keys["mark_in"] = f"{base}/mark/in"
    return keys


#: Requests waiting for the session desk at most (beyond: refused, counted; a query is told).
REQUEST_INBOX_SIZE = 256


@dataclass(frozen=True)
class Request:
    """One marker or condition request from zenoh.

    Attributes
    ----------
    kind : str
        ``"mark"`` (a query: acknowledge it), ``"mark_in"`` (a put: nobody to tell) or
        ``"condition"`` (a query).
    payload : bytes
        What the sender sent (JSON, or for a put also plain text: the label).
    query : object or None
        The zenoh query to reply to and drop (None for a put).
    received_ns : int
        Host UNIX time it arrived, ns.
    """

    kind: str
    payload: bytes
    query: Any
    received_ns: int


class RequestInbox:
    """A bounded, thread-safe queue of :class:`Request` (zenoh's callbacks put, the session
    desk takes). A full inbox refuses: a query gets an error reply at once, a put is
    counted in ``refused`` — never silently lost."""

    def __init__(self, capacity: int = REQUEST_INBOX_SIZE) -> None:
        self._pending: deque[Request] = deque()
        self._capacity = capacity
        self._ready = threading.Condition()
        self.refused = 0

    def offer(self, request: Request) -> bool:
        """Queue ``request``; False (counted in ``refused``) when the inbox is full."""
        with self._ready:
            if len(self._pending) >= self._capacity:
                self.refused += 1
                return False
            self._pending.append(request)
            self._ready.notify()
        return True

    def wake(self) -> None:
        """Wake a :meth:`take` that is waiting (nothing queued, nothing counted)."""
        with self._ready:
            self._ready.notify_all()

    def take(self, timeout_s: float) -> list[Request]:
        """Every queued request, oldest first, waiting up to ``timeout_s`` for one."""
        with self._ready:
            if not self._pending:
                self._ready.wait(timeout_s)
            taken = list(self._pending)
            self._pending.clear()
        return taken


def _base_config(mode: str, listen: tuple[str, ...], connect: tuple[str, ...], scout: bool) -> Any:
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(scout))
    return conf


def zenoh_config(cfg: ZenohConfig) -> Any:
    """The ``zenoh.Config`` for ``cfg``.

    Raises
    ------
    ConfigError
        ``config_file`` missing or not a valid zenoh json5 config.
    """
    if cfg.config_file:
        return _config_from_file(cfg.config_file, "zenoh.config_file")
    listen = cfg.listen if cfg.mode == "peer" else ()  # a client only connects
    conf = _base_config(cfg.mode, listen, cfg.connect, cfg.multicast_scouting)
    conf.insert_json5("scouting/gossip/enabled", json.dumps(cfg.gossip_scouting))
    return conf


#: Environment variable naming a zenoh json5 file for every viewer session (``rtsid watch``,
#: ``rtsid query``, the web page): a secure lab's ``viewer-NAME.json5`` from ``rtsid certs``.
VIEWER_CONFIG_ENV = "RTSID_ZENOH_CONFIG"


def subscriber_config(
    connect: tuple[str, ...], mode: str = "peer", config_file: str | None = None
) -> Any:
    """A listener-less session connecting to ``connect`` with scouting off (``rtsid watch``).

    ``config_file`` (default: the ``RTSID_ZENOH_CONFIG`` environment variable) names a zenoh
    json5 file that replaces ``connect`` and ``mode`` entirely, e.g. a viewer's TLS
    certificate and the router's ``tls/`` endpoint in the secure lab profile (docs/lab.md).

    Raises
    ------
    ConfigError
        ``config_file`` missing or not a valid zenoh json5 config.
    """
    if config_file is None:
        config_file = os.environ.get(VIEWER_CONFIG_ENV, "")
    if config_file:
        return _config_from_file(config_file, VIEWER_CONFIG_ENV)
    conf = _base_config(mode, (), connect, False)
    conf.insert_json5("scouting/gossip/enabled", "false")
    return conf


@dataclass(frozen=True)
class RouterConfig:
    """The ``[router]`` section of ``rtsid router``'s config file.

    Attributes
    ----------
    listen : tuple of str
        Endpoints the router listens on (default loopback only; a lab opens e.g.
        ``"tcp/0.0.0.0:7447"`` or one interface's address explicitly).
    config_file : str
        A zenoh json5 file (the one a ``zenohd`` would use) that replaces ``listen`` and
        the scouting settings. Empty: not used.
    """

    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    config_file: str = ""

    def __post_init__(self) -> None:
        if not self.listen and not self.config_file:
            raise invalid("listen", [], "at least one endpoint, e.g. 'tcp/127.0.0.1:7447'")
        for endpoint in self.listen:
            if not ENDPOINT_PATTERN.match(endpoint):
                raise invalid("listen", endpoint, "endpoints like 'tcp/127.0.0.1:7447'")
        if self.config_file and self.listen != RouterConfig().listen:
            raise invalid(
                "listen",
                list(self.listen),
                "its default when config_file is set (the json5 file names the endpoints)",
            )

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any] | None) -> RouterConfig:
        """Build from the ``[router]`` TOML table (unknown keys and bad values rejected)."""
        return section_from_mapping(cls, mapping, "router")


def open_when_reachable(conf: Any, timeout_s: float = 30.0) -> Any:
    """``zenoh.open(conf)``, retried every 0.2 s while the endpoint it connects to is not yet
    listening (a daemon or router still starting), until ``timeout_s``; then the error."""
    import zenoh

    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return zenoh.open(conf)
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


_RUST_SOURCE = re.compile(r"\s+at \S+\.rs:\d+\.?")


def zenoh_error_text(exc: BaseException) -> str:
    """zenoh's error message without the Rust source locations it appends (`` at
    /root/.cargo/…/unicast.rs:338.``): they name zenoh's code, not the user's problem."""
    return _RUST_SOURCE.sub("", str(exc)).strip()


def router_config(cfg: RouterConfig) -> Any:
    """The ``zenoh.Config`` of a router (eclipse-zenoh's router mode) for ``cfg``.

    Without ``config_file``: router mode, ``listen`` endpoints, no connect endpoints,
    multicast and gossip scouting off (nothing leaves the listed endpoints).

    Raises
    ------
    ConfigError
        ``config_file`` missing, not valid json5 or not in router mode.
    """
    if cfg.config_file:
        conf = _config_from_file(cfg.config_file, "router.config_file")
        if json.loads(conf.get_json("mode")) != "router":
            raise ConfigError(
                f"config key 'router.config_file' = {cfg.config_file!r} is not in router mode; "
                'set mode: "router" in it'
            )
        return conf
    conf = _base_config("router", cfg.listen, (), False)
    conf.insert_json5("scouting/gossip/enabled", "false")
    return conf


def _config_from_file(path_text: str, key: str) -> Any:
    import zenoh

    path = Path(path_text)
    if not path.is_file():
        raise ConfigError(
            f"config key {key!r} = {path_text!r}: no such file; give the path of a zenoh json5 "
            "config"
        )
    try:
        return zenoh.Config.from_file(str(path))
    except zenoh.ZError as exc:
        raise ConfigError(
            f"config key {key!r} = {path_text!r} is not a valid zenoh config: {exc}"
        ) from None


class _Entities:
    """An open session and what was declared on it."""

    def __init__(
        self, session: Any, publishers: dict[str, Any], others: list[Any], client: bool
    ) -> None:
        self.session = session
        self.publishers = publishers
        self.others = others
        self.client = client  # a client reaches nobody while it has no router

    def has_route(self) -> bool:
        """Whether a put can leave this session: always for a peer (whoever connects to it
        gets it), only while a router is connected for a client."""
        if not self.client:
            return True
        try:
            return bool(self.session.info.routers_zid())  # < 1 µs
        except Exception:  # a closing session
            return False


class ZenohPublisher:
    """Publish rtsid messages over zenoh (a context manager; never raises into the caller).

    Parameters
    ----------
    cfg : ZenohConfig
        The ``[zenoh]`` section.
    run_config : Mapping, optional
        What the ``config`` queryable answers (the daemon's configuration).
    rates_hz : Mapping[str, float], optional
        Expected rate of each published channel, Hz (sizes the history rings; e.g.
        ``{"estimate": 50, "status": 2}``).
    requests : RequestInbox, optional
        Where marker and condition requests go (the ``mark``, ``mark/in`` and ``condition``
        keys are declared only with it).

    Examples
    --------
    >>> with ZenohPublisher(ZenohConfig(listen=("tcp/127.0.0.1:7447",))) as z:  # doctest: +SKIP
    ...     z.publish_estimate(estimate_dict)
    ...     z.publish_status(status_dict)
    """

    def __init__(
        self,
        cfg: ZenohConfig,
        *,
        run_config: Mapping[str, Any] | None = None,
        rates_hz: Mapping[str, float] | None = None,
        requests: RequestInbox | None = None,
    ) -> None:
        self.cfg = cfg
        self.requests = requests
        self.keys = key_expressions(cfg)
        #: Every published message but samples, kept for the ``history`` queryable.
        self.history = HistoryStore(cfg.history_s, rates_hz) if cfg.history_s > 0 else None
        self._latest: dict[str, bytes] = {}  # newest payload per channel (written before put)
        self._lock = threading.Lock()  # session swaps
        self._count_lock = threading.Lock()  # counters touched by callers and zenoh threads
        self._entities: _Entities | None = None
        self._stop = threading.Event()
        self._retry_thread: threading.Thread | None = None
        self._config_bytes = encode_json(run_config or {})
        self._published = 0
        self._not_published = dict.fromkeys(NOT_PUBLISHED_REASONS, 0)
        self._errors = 0
        self._open_attempts = 0
        self._queries = 0
        self._query_errors = 0
        self._router_lost = False
        self._last_error: str | None = None
        self._state = "disabled" if not cfg.enabled else "starting"

    # ------------------------------------------------------------------ life cycle
    def start(self) -> ZenohPublisher:
        """Open the session and declare everything; on failure keep running and retry."""
        if not self.cfg.enabled or self._state != "starting":
            return self
        if not self._try_open():
            self._retry_thread = threading.Thread(
                target=self._retry_loop, name="rtsid-zenoh-open", daemon=True
            )
            self._retry_thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Stop retrying, undeclare everything and close the session.

        Returns
        -------
        bool
            Whether the retry thread (if any) ended within ``timeout_s``.
        """
        self._stop.set()
        ended = True
        thread, self._retry_thread = self._retry_thread, None
        if thread is not None:
            thread.join(timeout_s)
            ended = not thread.is_alive()
        with self._lock:
            entities, self._entities = self._entities, None
            if self._state != "disabled":
                self._state = "closed"
        if entities is not None:
            self._close(entities)
        return ended

    def __enter__(self) -> ZenohPublisher:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    @property
    def is_up(self) -> bool:
        """True while a session is open."""
        return self._entities is not None

    # ------------------------------------------------------------------ publishing
    def publish_estimate(self, message: Mapping[str, Any] | bytes) -> bool:
        """Publish one estimate (dict with ESTIMATE_FIELDS, or encoded bytes).

        Returns
        -------
        bool
            True if handed to zenoh; False when the session is down (counted).
        """
        payload = message if isinstance(message, bytes) else encode_estimate(message)
        return self._put("estimate", payload)

    def publish_status(self, message: Mapping[str, Any] | bytes) -> bool:
        """Publish a status message; it also becomes the ``status`` queryable's answer."""
        payload = message if isinstance(message, bytes) else encode_status(message)
        return self._put("status", payload)

    def publish_reflex(self, message: Mapping[str, Any] | bytes) -> bool:
        """Publish one slow-lane fit (REFLEX_SCHEMA)."""
        payload = message if isinstance(message, bytes) else encode_json(message)
        return self._put("reflex", payload)

    def publish_session(self, message: Mapping[str, Any] | bytes) -> bool:
        """Publish a session message (SESSION_SCHEMA); it also becomes the ``session``
        queryable's answer."""
        payload = message if isinstance(message, bytes) else encode_json(message)
        return self._put("session", payload)

    def publish_marker(self, message: Mapping[str, Any] | bytes) -> bool:
        """Publish one recorded marker (MARKER_SCHEMA)."""
        payload = message if isinstance(message, bytes) else encode_json(message)
        return self._put("marker", payload)

    def publish_samples(
        self,
        first_index: int,
        position_rad: Any,
        torque_nm: Any,
        valid: Any,
        status: Any,
        *,
        fs_hz: float,
    ) -> bool:
        """Publish a batch of raw samples when ``publish_samples`` is on (else returns False).

        Same arguments as :meth:`rtsid.io.mcap_log.McapLogger.log_samples` plus the sample
        rate; encoded on the calling thread (≈ 0.6 ms for 250 samples).
        """
        if not self.cfg.publish_samples:
            return False
        payload = encode_samples(first_index, fs_hz, position_rad, torque_nm, valid, status)
        return self._put("samples", payload)

    def compact_history(self) -> int:
        """Compress the history's sealed blocks (:meth:`rtsid.io.history.HistoryStore.compact`);
        call it from a housekeeping thread, never from a publishing one. Returns the blocks
        packed."""
        return 0 if self.history is None else self.history.compact()

    @property
    def history_compaction_due(self) -> bool:
        """The history sealed a block since its last compaction (:meth:`compact_history` has
        work to do)."""
        return self.history is not None and self.history.compaction_due

    def set_run_config(self, run_config: Mapping[str, Any]) -> None:
        """Replace what the ``config`` queryable answers."""
        self._config_bytes = encode_json(run_config)

    def _put(self, name: str, payload: bytes) -> bool:
        if name != "samples":  # kept even while the session is down: it answers once up
            self._latest[name] = payload
            if self.history is not None:
                self.history.append(name, payload)
        entities = self._entities
        if entities is None or not entities.has_route():
            reason = "session_down" if entities is None else "no_router"
            with self._count_lock:
                self._not_published[reason] += 1
            return False
        try:
            entities.publishers[name].put(payload)
        except Exception as exc:  # zenoh raises ZError; nothing may reach the caller
            self._record_error(f"zenoh put on {self.keys[name]} failed: {exc}")
            return False
        with self._count_lock:
            self._published += 1
        return True

    def stats(self) -> dict[str, Any]:
        """The ``zenoh`` object of the status message.

        Returns
        -------
        dict
            ``state`` (disabled, starting, up, down, router_lost, closed), ``mode``, ``listen``,
            ``connect``, ``published`` (handed to zenoh with a way out: a peer's open
            session, a client's connected router), ``not_published`` (messages that went
            nowhere) and ``not_published_by_reason`` (``session_down``: no session;
            ``no_router``: a client's router was gone), ``errors``, ``last_error``,
            ``open_attempts``, ``queries`` (answered), ``query_errors`` (malformed queries
            answered with an error reply), ``history_s``, ``history_bytes`` (the bytes the
            history ring holds: deflated blocks and the open one).
        """
        with self._count_lock:
            not_published = dict(self._not_published)
        return {
            "state": self._link_state(),
            "mode": self.cfg.mode,
            "listen": list(self.cfg.listen) if self.cfg.mode == "peer" else [],
            "connect": list(self.cfg.connect),
            "published": self._published,
            "not_published": sum(not_published.values()),
            "not_published_by_reason": not_published,
            "errors": self._errors,
            "last_error": self._last_error,
            "open_attempts": self._open_attempts,
            "queries": self._queries,
            "query_errors": self._query_errors,
            "history_s": self.cfg.history_s,
            "history_bytes": 0 if self.history is None else self.history.held_bytes,
        }

    def _link_state(self) -> str:
        """``state``, with ``router_lost`` while a client's session has no router (zenoh
        reconnects by itself; said once when it goes and once when it is back)."""
        entities = self._entities
        if self._state != "up" or entities is None or not entities.client:
            return self._state
        connected = entities.has_route()
        if connected == self._router_lost:  # a transition
            self._router_lost = not connected
            if connected:
                log.warning("zenoh router at %s is back", ", ".join(self.cfg.connect))
            else:
                log.warning(
                    "zenoh router at %s lost; estimates are still logged and zenoh reconnects "
                    "by itself",
                    ", ".join(self.cfg.connect),
                )
        return "router_lost" if self._router_lost else "up"

    # ------------------------------------------------------------------ session
    def _try_open(self) -> bool:
        import zenoh

        self._open_attempts += 1
        session = None
        try:
            conf = zenoh_config(self.cfg)
            session = zenoh.open(conf)
            entities = self._declare(session, client=json.loads(conf.get_json("mode")) == "client")
        except Exception as exc:  # ZError (port taken, bad endpoint) or ConfigError
            if session is not None:
                try:
                    session.close()
                except Exception:
                    pass
            self._record_error(self._open_failure(exc))
            with self._lock:
                if self._state not in ("closed",):
                    self._state = "down"
            return False
        with self._lock:
            if self._stop.is_set():
                self._close(entities)
                return True
            self._entities = entities
            self._state = "up"
        log.info("zenoh %s session up; publishing under %s", self.cfg.mode, self.keys["estimate"])
        return True

    def _open_failure(self, exc: Exception) -> str:
        exc_text = zenoh_error_text(exc)
        retry = f"estimates are still logged, retrying every {self.cfg.retry_interval_s:g} s"
        if self.cfg.config_file:
            return f"zenoh session from {self.cfg.config_file} could not open: {exc_text}; {retry}"
        if self.cfg.mode == "client":
            return (
                f"zenoh router at {', '.join(self.cfg.connect)} is unreachable: {exc_text}; "
                f"{retry} (is `rtsid router` or zenohd running there? check zenoh.connect)"
            )
        where = ", ".join(self.cfg.listen + self.cfg.connect)
        return (
            f"zenoh session on {where} could not open: {exc_text}; {retry} (is another rtsid on "
            "this port? set zenoh.listen to a free one)"
        )

    def _declare(self, session: Any, *, client: bool) -> _Entities:
        import zenoh

        json_enc = zenoh.Encoding.APPLICATION_JSON
        drop = zenoh.CongestionControl.DROP
        publishers = {
            "estimate": session.declare_publisher(
                self.keys["estimate"],
                encoding=json_enc,
                congestion_control=drop,
                priority=zenoh.Priority.DATA_HIGH,
                express=True,
            ),
            "status": session.declare_publisher(
                self.keys["status"], encoding=json_enc, congestion_control=drop
            ),
            "samples": session.declare_publisher(
                self.keys["samples"], encoding=json_enc, congestion_control=drop
            ),
            "reflex": session.declare_publisher(
                self.keys["reflex"], encoding=json_enc, congestion_control=drop
            ),
            # a marker or a session change is rare and must not be dropped on congestion
            **{
                name: session.declare_publisher(
                    self.keys[name],
                    encoding=json_enc,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
                for name in ("session", "marker")
            },
        }
        others = [
            session.liveliness().declare_token(self.keys["alive"]),
            session.declare_queryable(self.keys["config"], self._answer_config),
            session.declare_queryable(self.keys["status"], self._answer_latest_status),
            session.declare_queryable(self.keys["estimate"], self._answer_latest_estimate),
            session.declare_queryable(self.keys["history"], self._answer_history),
            session.declare_queryable(self.keys["session"], self._answer_latest_session),
        ]
        if self.requests is not None:
            others += [
                session.declare_queryable(self.keys["mark"], self._take_mark),
                session.declare_queryable(self.keys["condition"], self._take_condition),
                session.declare_subscriber(self.keys["mark_in"], self._take_mark_put),
            ]
        return _Entities(session, publishers, others, client)

    def _answer_latest_session(self, query: Any) -> None:
        self._answer_latest(query, "session")

    def _take_mark(self, query: Any) -> None:
        self._take_query(query, "mark")

    def _take_condition(self, query: Any) -> None:
        self._take_query(query, "condition")

    def _take_query(self, query: Any, kind: str) -> None:
        """Queryable callback: hand the query to the session desk (which replies and drops
        it), or refuse it at once when the inbox is full."""
        payload = query.payload.to_bytes() if query.payload is not None else b""
        assert self.requests is not None
        if not self.requests.offer(Request(kind, payload, query, time.time_ns())):
            self._answer_error(
                query,
                f"{self.keys[kind]}: too many requests waiting "
                f"({REQUEST_INBOX_SIZE}); NOT recorded, send it again",
            )

    def _take_mark_put(self, sample: Any) -> None:
        """Subscriber callback: a put on ``mark/in`` (refused ones are counted by the inbox)."""
        assert self.requests is not None
        self.requests.offer(Request("mark_in", sample.payload.to_bytes(), None, time.time_ns()))

    def _answer_latest_estimate(self, query: Any) -> None:
        self._answer_latest(query, "estimate")

    def _answer_latest_status(self, query: Any) -> None:
        self._answer_latest(query, "status")

    def _answer_latest(self, query: Any, name: str) -> None:
        """The newest message of a channel; no reply at all while none was published."""
        latest = self._latest.get(name)
        self._answer(query, name, [] if latest is None else [latest])

    def _answer_config(self, query: Any) -> None:
        self._answer(query, "config", [self._config_bytes])

    def _answer_history(self, query: Any) -> None:
        """Estimates and status in the asked range, from a lock-free copy of the ring, built
        and sent here on zenoh's callback thread (never on the worker's)."""
        try:
            if self.history is None:
                raise QueryError("this daemon keeps no history (zenoh.history_s = 0)")
            request = parse_history_query(dict(query.parameters))
            parts = list(self.history.answer(request, robot=self.cfg.robot, joint=self.cfg.joint))
        except QueryError as exc:
            self._answer_error(query, f"{self.keys['history']}: {exc}")
            return
        except Exception as exc:  # never silence, never a traceback on zenoh's thread
            self._record_error(f"history query failed: {exc!r}")
            self._answer_error(query, f"{self.keys['history']}: the query could not be answered")
            return
        self._answer(query, "history", parts)

    def _answer(self, query: Any, name: str, payloads: list[bytes]) -> None:
        """Queryable callback: reply with prepared payloads and drop the query."""
        import zenoh

        try:
            with query:  # dropping the query finalizes it for the caller
                for payload in payloads:
                    query.reply(self.keys[name], payload, encoding=zenoh.Encoding.APPLICATION_JSON)
                with self._count_lock:
                    self._queries += 1
        except Exception as exc:  # never let an exception escape into zenoh's thread
            self._record_error(f"zenoh reply on {self.keys[name]} failed: {exc}")

    def _answer_error(self, query: Any, message: str) -> None:
        import zenoh

        try:
            with query:  # counted before dropping it finalizes the query for the caller
                query.reply_err(
                    encode_json({"error": message}), encoding=zenoh.Encoding.APPLICATION_JSON
                )
                with self._count_lock:
                    self._query_errors += 1
        except Exception as exc:
            self._record_error(f"zenoh error reply failed: {exc}")

    def _retry_loop(self) -> None:
        while not self._stop.wait(self.cfg.retry_interval_s):
            if self._try_open():
                return

    def _record_error(self, message: str) -> None:
        with self._count_lock:
            first = self._last_error is None
            self._errors += 1
            self._last_error = message
        (log.warning if first else log.debug)("%s", message)

    @staticmethod
    def _close(entities: _Entities) -> None:
        for entity in [*entities.others, *entities.publishers.values()]:
            try:
                entity.undeclare()
            except Exception:
                pass
        try:
            entities.session.close()
        except Exception as exc:
            log.debug("zenoh session close: %s", exc)


# ---------------------------------------------------------------------- the querying side
def user_key_expr(text: str, what: str = "key") -> str:
    """A key expression given by a user (``rtsid watch KEY``, ``rtsid query KEY``), checked by
    zenoh's own parser; a trailing ``/`` is dropped.

    Raises
    ------
    ConfigError
        Names the key, zenoh's reason and what is expected.
    """
    import zenoh

    key = text.rstrip("/")
    try:
        zenoh.KeyExpr(key)
    except zenoh.ZError as exc:
        reason = str(exc).split(" at /", 1)[0]
        raise ConfigError(
            f"{what} {text[:80]!r} is not a zenoh key expression ({reason}); expected e.g. "
            "rtsid/*/* or rtsid/<robot>/<joint>"
        ) from None
    return key


@dataclass(frozen=True)
class QueryAnswer:
    """What the daemons matching a key answered to a query.

    Attributes
    ----------
    replies : list of (str, bytes)
        Key expression and payload of each reply, in arrival order.
    errors : list of str
        Error replies (a malformed query), as text.
    """

    replies: list[tuple[str, bytes]]
    errors: list[str]


def query(
    session: Any, selector: str, *, timeout_s: float = 2.0, payload: bytes | None = None
) -> QueryAnswer:
    """Ask every queryable matching ``selector`` (``key?param=value;...``) and collect the
    replies, with consolidation off (a history answer comes in several parts).

    ``payload`` goes with the query (a marker's or a condition's JSON). Returns when every
    matching daemon has finished answering, or after ``timeout_s``.
    """
    import zenoh

    replies: list[tuple[str, bytes]] = []
    errors: list[str] = []
    handler = session.get(
        selector,
        zenoh.handlers.FifoChannel(4096),
        consolidation=zenoh.ConsolidationMode.NONE,
        target=zenoh.QueryTarget.ALL,
        timeout=timeout_s,
        payload=payload,
    )
    for reply in handler:
        if reply.ok is not None:
            replies.append((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))
        else:
            errors.append(reply.err.payload.to_bytes().decode("utf-8", "replace"))
    return QueryAnswer(replies, errors)
