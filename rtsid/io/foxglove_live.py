"""``rtsid run --foxglove [PORT]``: the recording's channels, live, over the Foxglove WebSocket
protocol (foxglove-sdk's server), so ``replay/foxglove_layout.json`` works on a running daemon
as it does on files.

Every message the MCAP logger writes is handed to :meth:`FoxgloveLive.tap` on the logger's
own thread (:class:`rtsid.io.mcap_log.McapLogger` ``tap``), so the live channels carry exactly
the recording's messages — same topics, schema names, JSON schemas (``jsonschema``) and JSON
payloads — and the window worker never waits for a viewer. The channel list is the logger's
(:func:`rtsid.io.mcap_log.channel_kinds`), so a channel added to the recording appears here
too. The server binds to 127.0.0.1 unless told otherwise; foxglove-sdk keeps at most
``backlog`` messages per client and drops the oldest for a slow one.

foxglove-sdk is an optional dependency (``pip install 'rtsid[live]'``).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable
from typing import Any

from rtsid.errors import ConfigError, ServiceError
from rtsid.io.access_token import is_loopback
from rtsid.io.schemas import SCHEMAS, encode_json

__all__ = ["FoxgloveLive", "require_foxglove"]

log = logging.getLogger(__name__)


def require_foxglove() -> Any:
    """Import foxglove-sdk, or say which extra installs it.

    Raises
    ------
    ConfigError
        foxglove-sdk is not installed.
    """
    try:
        import foxglove
    except ImportError:
        raise ConfigError(
            "--foxglove needs foxglove-sdk, which is not installed; install the extra: "
            "pip install 'rtsid[live]'"
        ) from None
    return foxglove


class FoxgloveLive:
    """A Foxglove WebSocket server carrying rtsid's channels (a context manager).

    Parameters
    ----------
    kinds : iterable of str
        Channel kinds to advertise (keys of :data:`~rtsid.io.schemas.SCHEMAS`).
    host : str
        Address to bind (default 127.0.0.1: this machine only).
    port : int
        TCP port (0: a free one; :attr:`port` says which).
    name : str
        Server name shown by Foxglove.
    backlog : int
        Messages buffered per client before the oldest is dropped.
    """

    def __init__(
        self,
        kinds: Iterable[str],
        *,
        host: str = "127.0.0.1",
        port: int = 8765,
        name: str = "rtsid",
        backlog: int = 1024,
    ) -> None:
        if not 0 <= port <= 65535:
            raise ConfigError(f"--foxglove port {port} is not accepted; expected 0…65535")
        if not is_loopback(host):
            raise ConfigError(
                f"--foxglove-host {host} is not accepted: Foxglove's WebSocket protocol has no "
                "authentication, so the server stays on loopback; from another machine tunnel "
                f"to it: ssh -L {port}:127.0.0.1:{port} THIS_HOST"
            )
        self.kinds = tuple(kinds)
        self.host = host
        self.requested_port = port
        self.port: int | None = None
        self.name = name
        self.backlog = backlog
        self._foxglove: Any = None
        self._context: Any = None
        self._server: Any = None
        self._channels: dict[str, Any] = {}
        self._lock = threading.Lock()  # channel creation (start, and a kind first seen in tap)
        self.sent = 0
        self.errors = 0

    def start(self) -> FoxgloveLive:
        """Create the channels and start the server.

        Raises
        ------
        ConfigError
            foxglove-sdk missing (names the extra).
        ServiceError
            The server could not bind (port taken), naming the address and the fix.
        """
        foxglove = require_foxglove()
        self._foxglove = foxglove
        self._context = foxglove.Context()
        for kind in self.kinds:
            self._channel(kind)
        try:
            self._server = foxglove.start_server(
                name=self.name,
                host=self.host,
                port=self.requested_port,
                context=self._context,
                message_backlog_size=self.backlog,
            )
        except Exception as exc:  # foxglove raises its own error type for a taken port
            raise ServiceError(
                f"Foxglove server on {self.host}:{self.requested_port} could not start: {exc}; "
                "choose a free port with --foxglove PORT"
            ) from None
        self.port = int(self._server.port)
        return self

    def stop(self) -> None:
        """Stop the server and close the channels (idempotent)."""
        server, self._server = self._server, None
        if server is not None:
            server.stop()
        with self._lock:
            channels, self._channels = self._channels, {}
        for channel in channels.values():
            channel.close()

    def __enter__(self) -> FoxgloveLive:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    @property
    def url(self) -> str:
        """``ws://host:port`` to give Foxglove's "Open connection" dialog."""
        return f"ws://{self.host}:{self.port}"

    def _channel(self, kind: str) -> Any:
        with self._lock:
            channel = self._channels.get(kind)
            if channel is None and kind in SCHEMAS and self._foxglove is not None:
                schema, topic = SCHEMAS[kind]
                channel = self._foxglove.Channel(
                    topic,
                    schema=self._foxglove.Schema(
                        name=schema["title"], encoding="jsonschema", data=encode_json(schema)
                    ),
                    message_encoding="json",
                    context=self._context,
                )
                self._channels[kind] = channel
            return channel

    def tap(self, kind: str, log_time_ns: int, payload: bytes) -> None:
        """Send one recorded message to the connected clients (never raises, never blocks)."""
        channel = self._channels.get(kind) or self._channel(kind)
        if channel is None or self._server is None:
            return
        try:
            channel.log(payload, log_time=log_time_ns)
            self.sent += 1
        except Exception as exc:
            self.errors += 1
            if self.errors == 1:
                log.warning("Foxglove live: sending on %s failed: %s", kind, exc)
