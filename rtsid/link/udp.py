"""A UDP source: datagrams of samples from a real-time target (Simulink Real-Time, LabVIEW,
Beckhoff …), and the plant's sender of the same stream.

``[link] interface = "udp"`` with a ``[link.udp]`` layout
(:class:`~rtsid.link.config.UdpConfig`): each datagram holds ``samples_per_datagram``
samples, each packed as ``sample_format`` in ``byte_order``, the codes named by ``fields``.
:func:`compile_layout` checks the layout when the config loads and gives a
:class:`UdpLayout`. The receiving side is only the bus-reading part:
:class:`UdpReceiver` has the ``recv(timeout)``/``shutdown()`` of a python-can bus and
returns :class:`Datagram` objects, which the one :class:`~rtsid.link.acquisition.Acquisition`
decodes (:class:`UdpDecoder`) and sequences with the same counter unwrap, gap, duplicate and
reorder bookkeeping as CAN frames. A datagram of the wrong length is ``malformed``; nothing
in a datagram can raise out of the decoder.

The socket binds 127.0.0.1 by default; a lab opens another address explicitly
(``bind_host``), as with rtsid's other servers. Never multicast.
"""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import ConfigError

__all__ = [
    "UDP_FIELDS",
    "Datagram",
    "UdpDecoder",
    "UdpLayout",
    "UdpReceiver",
    "UdpSender",
    "compile_layout",
]

#: Names a ``[link.udp] fields`` entry may take (``_``: a value to ignore).
UDP_FIELDS = ("counter", "position", "torque", "status", "marker", "_")
_CODES = {
    "b": "i1",
    "B": "u1",
    "h": "i2",
    "H": "u2",
    "i": "i4",
    "I": "u4",
    "l": "i4",
    "L": "u4",
    "q": "i8",
    "Q": "u8",
    "f": "f4",
    "d": "f8",
}
_UNSIGNED = "BHILQ"


class Datagram:
    """One received datagram and its arrival time (wall clock, s)."""

    __slots__ = ("data", "timestamp")

    def __init__(self, data: bytes, timestamp: float) -> None:
        self.data = data
        self.timestamp = timestamp


class UdpLayout:
    """A compiled ``[link.udp]`` layout (immutable).

    Attributes
    ----------
    dtype : numpy.dtype
        One sample as a structured dtype.
    datagram_bytes : int
        Exact length of a datagram.
    counter_modulo : int
        ``2**bits`` of the counter field.
    samples_per_unit : int
        Samples per datagram (the plant's unit of faults).
    """

    def __init__(self, cfg: Any) -> None:
        order = "<" if cfg.byte_order == "little" else ">"
        fmt = cfg.sample_format
        where = f"[link.udp] sample_format {fmt!r}"
        if len(fmt) != len(cfg.fields):
            raise ConfigError(
                f"{where} has {len(fmt)} codes but fields names {len(cfg.fields)}; give one "
                "name per code (repeat counts are not accepted)"
            )
        bad = [c for c in fmt if c not in _CODES]
        if bad:
            raise ConfigError(
                f"{where}: code {bad[0]!r} is not accepted; use one of {''.join(_CODES)}"
            )
        names = [n for n in cfg.fields if n != "_"]
        for required in ("counter", "position", "torque"):
            if required not in names:
                raise ConfigError(
                    f"[link.udp] fields {list(cfg.fields)} has no {required!r}; name the "
                    f"{required} field (a counter is required: gaps come from it)"
                )
        if len(set(names)) != len(names):
            raise ConfigError(f"[link.udp] fields {list(cfg.fields)} names a field twice")
        codes = dict(zip(cfg.fields, fmt, strict=True))
        if codes["counter"] not in _UNSIGNED:
            raise ConfigError(
                f"[link.udp] the counter's code {codes['counter']!r} is not an unsigned "
                "integer; use B, H, I or Q"
            )
        self.dtype = np.dtype(
            [
                (name if name != "_" else f"_{k}", order + _CODES[code])
                for k, (name, code) in enumerate(zip(cfg.fields, fmt, strict=True))
            ]
        )
        assert self.dtype.itemsize == struct.calcsize(order + fmt)
        self.codes = codes
        self.samples_per_unit = int(cfg.samples_per_datagram)
        self.datagram_bytes = self.dtype.itemsize * self.samples_per_unit
        self.counter_modulo = 1 << (8 * struct.calcsize(codes["counter"]))
        self.position_factor = float(cfg.position_scale * cfg.position_sign)
        self.torque_factor = float(cfg.torque_scale * cfg.torque_sign)
        self.has_status = "status" in codes
        self.has_marker = "marker" in codes
        self.uses_timestamps = False

    def decoder(self) -> UdpDecoder:
        """A fresh decoder (it remembers the marker's last value)."""
        return UdpDecoder(self)

    # ------------------------------------------------------------------ the plant's side
    def _quantise(
        self, name: str, values: NDArray[np.float64], factor: float
    ) -> tuple[NDArray[Any], NDArray[np.bool_]]:
        kind = np.dtype(_CODES[self.codes[name]])
        scaled = np.asarray(values, dtype=float) / factor
        if kind.kind == "f":
            return scaled, np.zeros(scaled.size, dtype=bool)
        info = np.iinfo(kind)
        raw = np.rint(scaled)
        clipped = (raw < info.min) | (raw > info.max)
        return np.clip(raw, info.min, info.max).astype(np.int64), clipped

    def quantise(
        self, position_rad: NDArray[np.float64], torque_nm: NDArray[np.float64]
    ) -> tuple[NDArray[Any], NDArray[np.bool_], NDArray[Any], NDArray[np.bool_]]:
        """Raw position and torque values and where each was clipped to its field."""
        pos, pos_sat = self._quantise("position", position_rad, self.position_factor)
        trq, trq_sat = self._quantise("torque", torque_nm, self.torque_factor)
        return pos, pos_sat, trq, trq_sat

    def to_si(
        self, position_raw: NDArray[Any], torque_raw: NDArray[Any]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Position (rad) and torque (N·m) of raw values, as the decoder computes them."""
        pos = np.asarray(position_raw, dtype=self.dtype["position"]).astype(float)
        trq = np.asarray(torque_raw, dtype=self.dtype["torque"]).astype(float)
        return pos * self.position_factor, trq * self.torque_factor

    def encode_samples(
        self,
        index: NDArray[np.int64],
        position_raw: NDArray[Any],
        torque_raw: NDArray[Any],
        status: NDArray[np.int64],
        *,
        marker: NDArray[np.int64] | None = None,
        **_: Any,
    ) -> list[list[bytes]]:
        """Datagrams of ``samples_per_datagram`` consecutive samples, one group each.

        ``index.size`` must be a multiple of ``samples_per_datagram`` (the plant cuts
        its blocks so).
        """
        rows = np.zeros(index.size, dtype=self.dtype)
        rows["counter"] = index % self.counter_modulo
        rows["position"] = position_raw
        rows["torque"] = torque_raw
        if self.has_status:
            rows["status"] = status
        if self.has_marker and marker is not None:
            rows["marker"] = marker
        raw = rows.tobytes()
        size = self.datagram_bytes
        return [[raw[k : k + size]] for k in range(0, len(raw), size)]


class UdpDecoder:
    """Turns a datagram into samples; never raises (a bad datagram gives None)."""

    unpaired = 0

    def __init__(self, layout: UdpLayout) -> None:
        self.layout = layout
        self._marker_last: float | None = None

    def decode(self, data: bytes) -> list[tuple[Any, float, float, int, str | None]] | None:
        """``[(counter, position rad, torque N·m, status, marker label or None), …]``, or None
        when the datagram has the wrong length."""
        layout = self.layout
        if len(data) != layout.datagram_bytes:
            return None
        rows = np.frombuffer(data, dtype=layout.dtype)
        counters = rows["counter"].tolist()
        positions = (rows["position"] * layout.position_factor).tolist()
        torques = (rows["torque"] * layout.torque_factor).tolist()
        if not all(np.isfinite(positions)) or not all(np.isfinite(torques)):
            return None
        status = (
            (rows["status"].astype(np.int64) & 0xF).tolist()
            if layout.has_status
            else [0] * len(counters)
        )
        markers: list[str | None] = [None] * len(counters)
        if layout.has_marker:
            for k, value in enumerate(rows["marker"].tolist()):
                if self._marker_last is not None and value != self._marker_last:
                    markers[k] = f"marker={value:g}"
                self._marker_last = value
        return list(zip(counters, positions, torques, status, markers, strict=True))


def compile_layout(cfg: Any) -> UdpLayout:
    """Check a ``[link.udp]`` section and compile it (ConfigError naming the problem)."""
    return UdpLayout(cfg)


def _family(host: str) -> socket.AddressFamily:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


class UdpReceiver:
    """A bound UDP socket with the ``recv(timeout)``/``shutdown()`` of a python-can bus.

    Parameters
    ----------
    host, port : str, int
        Address to bind (port 0: a free one; :attr:`port` tells which).
    max_bytes : int
        Largest datagram read (a longer one is truncated and then malformed).
    receive_buffer_bytes : int
        ``SO_RCVBUF``.
    """

    def __init__(
        self, host: str, port: int, max_bytes: int, receive_buffer_bytes: int = 1 << 20
    ) -> None:
        self.sock = socket.socket(_family(host), socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer_bytes)
            self.sock.bind((host, port))
        except OSError:
            self.sock.close()
            raise
        self.port = int(self.sock.getsockname()[1])
        self.max_bytes = max(int(max_bytes) + 1, 2048)
        self._timeout: float | None = None

    def recv(self, timeout: float | None = None) -> Datagram | None:
        """The next datagram, or None after ``timeout`` s."""
        if timeout != self._timeout:
            self.sock.settimeout(timeout)
            self._timeout = timeout
        try:
            data = self.sock.recv(self.max_bytes)
        except TimeoutError:
            return None
        return Datagram(data, time.time())

    def send(self, msg: Any, timeout: float | None = None) -> None:
        """A UDP source carries no commands."""
        raise OSError("the UDP source has no command channel; drive the target itself")

    def shutdown(self) -> None:
        """Close the socket."""
        self.sock.close()


class UdpSender:
    """The plant's frame sink for UDP: sends each datagram to ``host:port``.

    Parameters
    ----------
    host, port : str, int
        Where the acquisition listens (127.0.0.1 in tests and the demo).
    """

    def __init__(self, host: str, port: int) -> None:
        self.address = (host, port)
        self.sock = socket.socket(_family(host), socket.SOCK_DGRAM)

    def send_frames(self, frames: Sequence[bytes]) -> int:
        """Send the datagrams in order; return how many the kernel refused."""
        failed = 0
        for data in frames:
            try:
                self.sock.sendto(data, self.address)
            except OSError:
                failed += 1
        return failed

    def poll_received(self) -> list[Any]:
        """The UDP stream is one-way: no commands come back."""
        return []

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()
