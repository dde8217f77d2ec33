"""The socketcand protocol: a server on loopback (the virtual plant as its own process) and
the client the acquisition reads it with.

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

The client (:class:`SocketcandBus`, what ``[link] interface = "socketcand"`` opens) is a
python-can bus with the same handshake as python-can's ``socketcand`` interface (greeting,
``< open CHANNEL >``, ``< rawmode >``, ``< send … >`` in python-can's format), but bounded in
time (connect and each handshake reply within ``timeout_s``; python-can's retries ``connect``
for 10 s and waits for the greeting forever) and it reads in batches:
:meth:`SocketcandBus.recv_chunk` takes what the socket holds in one read, every complete
record of it, so the acquisition can decode a read's frames together (compiled, or with one
regular expression, :func:`parse_records`) instead of one ``can.Message`` per frame (python-can
parses a read into ``can.Message`` objects handed out one ``recv`` at a time).
A closed connection raises :class:`can.CanOperationError` (the acquisition reconnects);
python-can's client then returned ``None`` from every ``recv`` until the link went stale.

One thread ("rtsid-socketcand") accepts clients and reads their commands; the plant thread
writes frames directly to every raw-mode client's socket (non-blocking, one ``send`` per
batch). A client that cannot keep up has a bounded backlog; beyond it, frames are dropped
for that client and counted.
"""

from __future__ import annotations

import collections
import re
import selectors
import socket
import struct
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import can

from rtsid.errors import ConfigError, LinkError, LinkHandshakeError
from rtsid.lifecycle import ThreadOwner

__all__ = [
    "Record",
    "ServerCounters",
    "SocketcandBus",
    "SocketcandServer",
    "format_frame",
    "format_send",
    "parse_records",
    "parse_send",
    "record_message",
]

LOOPBACK_HOSTS = ("127.0.0.1", "::1", "localhost")
_MAX_COMMAND = 512
#: Longest unfinished record the client keeps waiting for (python-can's limit: 200 chars).
MAX_PENDING_RECORD = 200
_READ_BYTES = 1 << 16  # one read takes up to this much (≈ 1365 frames of 48 bytes)
#: One raw-mode record: ``< frame ID SEC.USEC DATA >`` or ``< error ID SEC.USEC >``; any other
#: ``< … >`` (``< ok >``, ``< echo >``, garbage) matches the last group alone.
_RECORD = re.compile(
    rb"<\s*(frame|error)\s+([0-9A-Fa-f]{1,8})\s+(\d+(?:\.\d*)?)\s*([0-9A-Fa-f]*)\s*>|(<[^<>]*>)"
)

#: A parsed record: (kind ``b"frame"``/``b"error"``, identifier hex, timestamp text, data hex).
Record = tuple[bytes, bytes, bytes, bytes]


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


def format_send(msg: can.Message) -> str:
    """A frame to send as the client's ``< send ID DLC b0 b1 … >`` command (python-can's
    format: bytes in lower-case hex without padding, the DLC in hex)."""
    ident = (
        f"{msg.arbitration_id & 0x1FFFFFFF:08X}"
        if msg.is_extended_id
        else f"{msg.arbitration_id & 0x7FF:03X}"
    )
    length = msg.dlc
    data = " ".join(f"{x:x}" for x in msg.data[:length])
    return f"< send {ident} {length:X} {data} >"


def parse_records(buffer: bytes) -> tuple[list[Record], int, int]:
    """Every complete raw-mode record in ``buffer``, in order.

    Parameters
    ----------
    buffer : bytes
        Bytes received, possibly ending inside a record.

    Returns
    -------
    records : list of Record
        ``(kind, identifier hex, timestamp text, data hex)`` of each frame and error record.
    consumed : int
        Bytes of ``buffer`` parsed (up to the last complete record's ``>``); keep the rest.
    other : int
        Complete records that are neither (``< ok >``, ``< echo >``, garbage): skipped, as
        python-can's client skips them.
    """
    end = buffer.rfind(b">") + 1
    if end == 0:
        return [], 0, 0
    found = _RECORD.findall(buffer, 0, end)
    records = [m[:4] for m in found if m[0]]
    return records, end, len(found) - len(records)


def record_message(record: Record, channel: str | None = None) -> can.Message:
    """One record as python-can's client builds it (``convert_ascii_message_to_can_message``:
    a 3-digit identifier is standard, any other width extended; an error record is an
    extended error frame with one zero data byte)."""
    kind, ident, stamp, data = record
    if kind == b"error":
        return can.Message(
            timestamp=float(stamp),
            arbitration_id=int(ident, 16) & 0x1FFFFFFF,
            is_error_frame=True,
            data=bytearray(1),
            dlc=1,
            is_extended_id=True,
            is_rx=True,
            channel=channel,
        )
    payload = bytearray.fromhex(data.decode("ascii"))
    return can.Message(
        timestamp=float(stamp),
        arbitration_id=int(ident, 16),
        data=payload,
        dlc=len(payload),
        is_extended_id=len(ident) != 3,
        is_rx=True,
        channel=channel,
    )


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


def _timeval(seconds: float) -> bytes:
    """A ``struct timeval`` for SO_RCVTIMEO/SO_SNDTIMEO (at least 1 µs: 0 would mean never)."""
    micros = max(1, round(seconds * 1e6))
    return struct.pack("ll", micros // 1_000_000, micros % 1_000_000)


class SocketcandBus(can.BusABC):
    """A raw-mode socketcand client that reads in batches (``[link] interface = "socketcand"``).

    Parameters
    ----------
    channel : str
        The bus the server is asked to ``open`` (e.g. ``"can0"``).
    host, port : str, int
        The server.
    tcp_tune : bool
        TCP_NODELAY, and TCP_QUICKACK after each read (as python-can's ``tcp_tune``).
    timeout_s : float
        Bound of the connection and of each handshake reply, s.
    **kwargs
        Passed to :class:`can.BusABC` (``can_filters``, …).

    Raises
    ------
    LinkError
        Nobody listens at ``host:port``; the server refused the channel.
    LinkHandshakeError
        The server accepted the connection but did not greet (or answer) within ``timeout_s``.

    Attributes
    ----------
    other_records : int
        Complete records that were neither a frame nor an error (skipped by ``recv``; the
        acquisition's :func:`parse_records` skips them too).
    discarded_bytes : int
        Bytes dropped as garbage (no ``<``, or an unfinished record longer than
        :data:`MAX_PENDING_RECORD`).
    """

    def __init__(
        self,
        channel: str,
        host: str,
        port: int,
        tcp_tune: bool = True,
        timeout_s: float = 1.0,
        **kwargs: Any,
    ) -> None:
        self.channel_info = f"socketcand on {channel}@{host}:{port}"
        self.channel = channel
        self._where = f"{host}:{port}"
        self._tcp_tune = tcp_tune
        self._pending = b""
        self._messages: collections.deque[can.Message] = collections.deque()
        self._timeout: float | None = None
        self.other_records = 0
        self.discarded_bytes = 0
        try:
            self._sock = socket.create_connection((host, port), timeout=timeout_s)
        except OSError as exc:
            raise LinkError(
                f"no socketcand server at {host}:{port} ({exc}); start it (e.g. "
                f"'rtsid plant --port {port}') or fix [link] host/port"
            ) from exc
        try:
            if tcp_tune:
                self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._handshake(channel, timeout_s)
            # From here the socket blocks in the kernel with SO_RCVTIMEO/SO_SNDTIMEO as its
            # bounds: a read is one system call and one release of the GIL (a Python timeout
            # polls first, a second call and a second wait for the GIL, per read)
            self._sock.settimeout(None)
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, _timeval(timeout_s))
        except BaseException:
            self._sock.close()
            raise
        super().__init__(channel=channel, **kwargs)

    # ------------------------------------------------------------------ handshake
    def _handshake(self, channel: str, timeout_s: float) -> None:
        if self._expect(timeout_s) != b"< hi >":
            raise LinkHandshakeError(
                f"the socketcand server at {self._where} did not greet with '< hi >'; "
                "restart it, or fix [link] host/port if something else listens there"
            )
        self._sock.sendall(f"< open {channel} >".encode("ascii"))
        reply = self._expect(timeout_s)
        if reply != b"< ok >":
            raise LinkError(
                f"the socketcand server at {self._where} refused to open channel {channel!r} "
                f"({reply.decode('ascii', 'replace')}); fix [link] channel"
            )
        self._sock.sendall(b"< rawmode >")
        reply = self._expect(timeout_s)
        if reply != b"< ok >":
            raise LinkError(
                f"the socketcand server at {self._where} refused raw mode "
                f"({reply.decode('ascii', 'replace')}); is it a socketcand server?"
            )

    def _expect(self, timeout_s: float) -> bytes:
        """The next record of the handshake (whitespace normalised), within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while b">" not in self._pending:
            left = deadline - time.monotonic()
            if left <= 0 or len(self._pending) > MAX_PENDING_RECORD:
                break
            self._sock.settimeout(left)
            try:
                chunk = self._sock.recv(256)
            except TimeoutError:
                break
            except OSError as exc:
                raise LinkError(f"the socketcand server at {self._where} failed: {exc}") from exc
            if not chunk:
                raise LinkError(
                    f"the socketcand server at {self._where} closed the connection during "
                    "the handshake; restart it, or fix [link] host/port"
                )
            self._pending += chunk
        end = self._pending.find(b">")
        if end < 0:
            raise LinkHandshakeError(
                f"the socketcand server at {self._where} accepted the connection but did not "
                f"greet ('< hi >') within {timeout_s:g} s; restart it, or fix [link] host/port "
                "if something else listens there"
            )
        start = self._pending.rfind(b"<", 0, end)
        record = b" ".join(self._pending[max(start, 0) : end + 1].split())
        self._pending = self._pending[end + 1 :]  # frames right after '< ok >' stay
        return record

    # ------------------------------------------------------------------ receiving
    def recv_chunk(self, timeout: float) -> bytes:
        """The complete records that arrive in one read (waiting at most ``timeout`` s for
        it), as received; ``b""`` when nothing came. A record cut by the read is kept for
        the next call.

        Raises
        ------
        can.CanOperationError
            The socket failed or the server closed the connection.
        """
        sock = self._sock
        if timeout != self._timeout:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, _timeval(timeout))
            self._timeout = timeout
        try:
            chunk = sock.recv(_READ_BYTES)
        except (TimeoutError, BlockingIOError):  # SO_RCVTIMEO passed: nothing came
            return b""
        except OSError as exc:
            raise can.CanOperationError(f"socketcand receive failed: {exc}") from exc
        if not chunk:
            raise can.CanOperationError(
                f"the socketcand server at {self._where} closed the connection"
            )
        if self._tcp_tune:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_QUICKACK, 1)
        if self._pending:
            chunk = self._pending + chunk
        end = chunk.rfind(b">") + 1
        rest = chunk[end:]
        if rest and (len(rest) > MAX_PENDING_RECORD or b"<" not in rest):
            self.discarded_bytes += len(rest)
            rest = b""
        self._pending = rest
        return chunk if end == len(chunk) else chunk[:end]

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        """python-can's per-frame ``recv`` (for tools; the acquisition uses recv_batch)."""
        if not self._messages:
            wait = 0.0 if timeout is None or timeout < 0 else timeout
            if timeout is None:
                wait = 3600.0
            records, _, other = parse_records(self.recv_chunk(max(wait, 1e-6)))
            self.other_records += other
            for record in records:
                self._messages.append(record_message(record, self.channel))
        if self._messages:
            return self._messages.popleft(), False
        return None, False

    # ------------------------------------------------------------------ sending
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send a frame (``< send … >``); ``timeout`` is ignored, as by python-can's client.

        Raises
        ------
        can.CanOperationError
            The socket failed.
        """
        try:
            self._sock.sendall(format_send(msg).encode("ascii"))
        except OSError as exc:
            raise can.CanOperationError(f"socketcand send failed: {exc}") from exc

    def shutdown(self) -> None:
        """Close the connection."""
        super().shutdown()
        self._sock.close()
