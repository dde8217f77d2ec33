"""A socketcand-protocol server on loopback, so the virtual plant can be its own process.

The server speaks the subset of the socketcand ASCII protocol (linux-can/socketcand
``doc/protocol.md``) that a raw-mode client uses, which is all python-can's ``socketcand``
interface needs::

    server: < hi >
    client: < open can0 >        server: < ok >      (another bus name: < error ... >, close)
    client: < rawmode >          server: < ok >
    server: < frame 100 1700000000.123456 0102030405060708 >     (one per CAN frame)
    server: < error 004 1700000000.123456 >                      (error frames)
    client: < send 200 8 1 0 0 0 0 0 0 0 >                       (frames to the robot)
    client: < echo >             server: < echo >

Frames are formatted as socketcand itself prints them (``%03X`` identifier, ``sec.usec``
timestamp of the moment they are written, data as contiguous upper-case hex).
python-can's client reads ``< ok >`` after ``rawmode`` with one ``recv``; a frame arriving in
the same TCP segment would break its handshake, so a client gets frames only
``handshake_pause_s`` after that ``< ok >`` (frames produced meanwhile are not sent to it).

One thread ("rtsid-socketcand") accepts clients and reads their commands; the plant thread
writes frames directly to every raw-mode client's socket (non-blocking, one ``send`` per
batch). A client that cannot keep up has a bounded backlog; beyond it, frames are dropped
for that client and counted.
"""

from __future__ import annotations

import collections
import selectors
import socket
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

import can

from rtsid.errors import ConfigError, LinkError
from rtsid.lifecycle import ThreadOwner

__all__ = ["ServerCounters", "SocketcandServer", "format_frame", "parse_send"]

LOOPBACK_HOSTS = ("127.0.0.1", "::1", "localhost")
_MAX_COMMAND = 512


def format_frame(msg: can.Message, timestamp: float) -> str:
    """One CAN frame as a socketcand raw-mode line (``< frame … >`` or ``< error … >``)."""
    seconds = int(timestamp)
    micros = int((timestamp - seconds) * 1e6)
    if msg.is_error_frame:
        return f"< error {msg.arbitration_id & 0x1FFFFFFF:03X} {seconds}.{micros:06d} >"
    ident = (
        f"{msg.arbitration_id & 0x1FFFFFFF:08X}"
        if msg.is_extended_id
        else f"{msg.arbitration_id & 0x7FF:03X}"
    )
    return f"< frame {ident} {seconds}.{micros:06d} {bytes(msg.data).hex().upper()} >"


def parse_send(command: str) -> can.Message | None:
    """A ``< send ID DLC b0 b1 … >`` command as a frame (None if it is not valid)."""
    parts = command[1:-1].split()
    if len(parts) < 3 or parts[0] != "send":
        return None
    try:
        ident = int(parts[1], 16)
        dlc = int(parts[2], 16)
        data = bytes(int(b, 16) for b in parts[3:])
    except ValueError:
        return None
    if dlc > 8 or len(data) != dlc:
        return None
    extended = len(parts[1]) == 8
    if ident > (0x1FFFFFFF if extended else 0x7FF):
        return None
    return can.Message(
        arbitration_id=ident, data=data, is_extended_id=extended, timestamp=time.time()
    )


@dataclass(frozen=True)
class ServerCounters:
    """What the server has done (snapshot)."""

    clients_connected: int
    clients_total: int
    frames_out: int
    frames_in: int
    dropped_slow_client: int
    dropped_inbox_full: int
    bad_commands: int


class _Client:
    def __init__(self, sock: socket.socket, address: object) -> None:
        self.sock = sock
        self.address = address
        self.state = "nobus"
        self.stream_after = float("inf")
        self.inbuf = ""
        self.outbuf = bytearray()
        self.lock = threading.Lock()
        self.closed = False


class SocketcandServer(ThreadOwner):
    """socketcand server for one CAN channel on 127.0.0.1 (a frame sink for the plant).

    Parameters
    ----------
    host : str
        Loopback address to listen on (``127.0.0.1`` or ``::1``).
    port : int
        TCP port (0: a free port; read :attr:`port` after :meth:`start`).
    channel : str
        The bus name clients must ``open`` (e.g. ``"can0"``).
    handshake_pause_s : float
        Delay between the ``rawmode`` reply and the first frame to that client.
    max_backlog_bytes : int
        Per-client bound of unsent frames (about 45 bytes each).
    max_inbox : int
        Bound of frames received from clients and not yet polled.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        channel: str = "can0",
        *,
        handshake_pause_s: float = 0.1,
        max_backlog_bytes: int = 4 << 20,
        max_inbox: int = 1024,
    ) -> None:
        if host not in LOOPBACK_HOSTS:
            raise ConfigError(
                f"socketcand server host {host!r} is not accepted; rtsid serves on loopback "
                "only ('127.0.0.1' or '::1') — run a real socketcand for remote access"
            )
        super().__init__("rtsid-socketcand")
        self.host = host
        self.channel = channel
        self.handshake_pause_s = handshake_pause_s
        self.max_backlog_bytes = max_backlog_bytes
        self._requested_port = port
        self.port = port
        self._listener: socket.socket | None = None
        self._selector = selectors.DefaultSelector()
        self._clients: list[_Client] = []
        self._clients_lock = threading.Lock()
        self._inbox: collections.deque[can.Message] = collections.deque(maxlen=max_inbox)
        self._c = dict.fromkeys(
            (
                "clients_total",
                "frames_out",
                "frames_in",
                "dropped_slow_client",
                "dropped_inbox_full",
                "bad_commands",
            ),
            0,
        )

    # ------------------------------------------------------------------ life cycle
    def _before_start(self) -> None:
        """Bind and listen (the I/O thread then accepts and serves)."""
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        listener = socket.socket(family, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            listener.bind((self.host, self._requested_port))
        except OSError as exc:
            listener.close()
            raise LinkError(
                f"cannot listen on {self.host}:{self._requested_port}: {exc}; choose another "
                "port (0 picks a free one)"
            ) from exc
        listener.listen(8)
        listener.setblocking(False)
        self.port = listener.getsockname()[1]
        self._listener = listener
        self._selector.register(listener, selectors.EVENT_READ, None)

    def _after_stop(self, ended: bool) -> None:
        """Close every socket (the I/O thread wakes every 20 ms to see the stop)."""
        with self._clients_lock:
            clients, self._clients = self._clients, []
        for client in clients:
            self._close_client(client, unregister=ended)
        if self._listener is not None:
            if ended:
                self._selector.unregister(self._listener)
            self._listener.close()
            self._listener = None
        if ended:
            self._selector.close()

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` the server listens on."""
        return self.host, self.port

    def counters(self) -> ServerCounters:
        """Snapshot of the counters."""
        with self._clients_lock:
            connected = len(self._clients)
        return ServerCounters(clients_connected=connected, **self._c)

    def raw_clients(self) -> int:
        """Clients in raw mode (receiving frames)."""
        with self._clients_lock:
            return sum(1 for c in self._clients if c.state == "raw")

    # ------------------------------------------------------------------ FrameSink
    def send_frames(self, frames: Sequence[can.Message]) -> int:
        """Write frames to every streaming client (non-blocking). Returns 0: a slow client's
        losses are counted per client in ``dropped_slow_client``, not as plant overflows.

        A client still in its post-``rawmode`` pause gets nothing (like socketcand, which
        delivers only what arrives after the client is streaming); ``frames_out`` counts
        frames delivered to at least one client.
        """
        if not frames:
            return 0
        mono = time.monotonic()
        with self._clients_lock:
            clients = [c for c in self._clients if c.state == "raw" and mono >= c.stream_after]
        if not clients:
            return 0
        now = time.time()  # a frame stamped by the plant (no-counter protocols) keeps its stamp
        data = "".join(format_frame(f, f.timestamp or now) for f in frames).encode("ascii")
        for client in clients:
            with client.lock:
                if len(client.outbuf) + len(data) > self.max_backlog_bytes:
                    self._c["dropped_slow_client"] += len(frames)
                    continue
                client.outbuf += data
                self._flush(client)
        self._c["frames_out"] += len(frames)
        return 0

    def poll_received(self) -> list[can.Message]:
        """Frames clients sent (``< send … >``) since the last call."""
        out = []
        while self._inbox:
            out.append(self._inbox.popleft())
        return out

    # ------------------------------------------------------------------ I/O thread
    def _run(self) -> None:
        while not self._stop.is_set():
            for key, _ in self._selector.select(timeout=0.02):
                if key.data is None:
                    self._accept()
                else:
                    self._read(key.data)
            self._flush_all()

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            sock, address = self._listener.accept()
        except BlockingIOError:
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        client = _Client(sock, address)
        self._selector.register(sock, selectors.EVENT_READ, client)
        with self._clients_lock:
            self._clients.append(client)
        self._c["clients_total"] += 1
        self._reply(client, "< hi >")

    def _read(self, client: _Client) -> None:
        try:
            chunk = client.sock.recv(4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            chunk = b""
        if not chunk:
            self._drop_client(client)
            return
        client.inbuf += chunk.decode("ascii", errors="replace")
        while True:
            start = client.inbuf.find("<")
            end = client.inbuf.find(">", start + 1)
            if start < 0 or end < 0:
                if len(client.inbuf) > _MAX_COMMAND:
                    client.inbuf = ""
                    self._c["bad_commands"] += 1
                break
            command = " ".join(client.inbuf[start : end + 1].split())
            client.inbuf = client.inbuf[end + 1 :]
            self._command(client, command)

    def _command(self, client: _Client, command: str) -> None:
        words = command[1:-1].split()
        verb = words[0] if words else ""
        if verb == "open" and client.state == "nobus":
            if len(words) == 2 and words[1] == self.channel:
                client.state = "bcm"
                self._reply(client, "< ok >")
            else:
                self._reply(client, "< error could not open bus >")
                self._drop_client(client)
        elif verb == "rawmode" and client.state in ("bcm", "raw"):
            client.stream_after = time.monotonic() + self.handshake_pause_s
            self._reply(client, "< ok >")
            client.state = "raw"
        elif verb == "bcmmode" and client.state == "raw":
            client.state = "bcm"
            self._reply(client, "< ok >")
        elif verb == "echo":
            self._reply(client, "< echo >")
        elif verb == "send" and client.state in ("bcm", "raw"):
            msg = parse_send(command)
            if msg is None:
                self._c["bad_commands"] += 1
                return
            if len(self._inbox) == self._inbox.maxlen:
                self._c["dropped_inbox_full"] += 1
            self._inbox.append(msg)
            self._c["frames_in"] += 1
        else:
            self._c["bad_commands"] += 1
            self._reply(client, "< error unknown command >")

    def _reply(self, client: _Client, text: str) -> None:
        with client.lock:
            client.outbuf += text.encode("ascii")
            self._flush(client)

    def _flush_all(self) -> None:
        now = time.monotonic()
        with self._clients_lock:
            clients = list(self._clients)
        for client in clients:
            if (client.outbuf and now >= client.stream_after) or client.state != "raw":
                with client.lock:
                    self._flush(client)

    def _flush(self, client: _Client) -> None:
        """Send what the socket takes now (caller holds ``client.lock``)."""
        if not client.outbuf or client.closed:
            return
        try:
            sent = client.sock.send(client.outbuf)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            client.outbuf.clear()
            return
        del client.outbuf[:sent]

    def _drop_client(self, client: _Client) -> None:
        with self._clients_lock:
            if client in self._clients:
                self._clients.remove(client)
        self._close_client(client, unregister=True)

    def _close_client(self, client: _Client, *, unregister: bool) -> None:
        with client.lock:
            if client.closed:
                return
            client.closed = True
        if unregister:
            try:
                self._selector.unregister(client.sock)
            except (KeyError, ValueError):
                pass
        client.sock.close()
