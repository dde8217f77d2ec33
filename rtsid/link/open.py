"""Open the link a config describes: a bus factory, and the embedded plant when asked for.

The daemon does::

    link_cfg, plant_cfg = load_link_configs(path)
    with open_link(link_cfg, plant_cfg) as link:
        ring = link.make_ring()
        with link.make_acquisition(ring) as acq:
            acq.send_command(Command(enable=True, kind="prbs", amplitude_rad=0.03))
            ...

``interface = "embedded"`` starts a :class:`~rtsid.link.plant.VirtualPlant` on a private
python-can ``virtual`` channel inside this process; every other interface opens a real
python-can bus (``socketcand``: rtsid's batch-reading client, connecting to ``host:port``,
e.g. ``rtsid plant``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import socket
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import can

from rtsid.config import invalid
from rtsid.errors import LinkError
from rtsid.link.acquisition import Acquisition
from rtsid.link.config import LinkConfig, PlantConfig
from rtsid.link.mapping import MappedProtocol, protocol_from_config
from rtsid.link.plant import VirtualPlant
from rtsid.link.ring import RingBuffer
from rtsid.link.socketcand import SocketcandBus
from rtsid.link.udp import UdpLayout, UdpReceiver, UdpSender, compile_layout

__all__ = ["LinkHandle", "bus_factory", "open_link"]

_NO_BITRATE = ("virtual", "embedded", "socketcand", "socketcan")
_HANDSHAKE_TIMEOUT_S = 1.0
_PLANT_RX_QUEUE = 1024
_LOOPBACK = ("127.0.0.1", "::1", "localhost")


@dataclass(frozen=True)
class LinkHandle:
    """What :func:`open_link` gives the daemon.

    Attributes
    ----------
    config : LinkConfig
        The ``[link]`` section in use.
    bus_factory : callable
        Opens a new bus each call (the acquisition calls it again to reconnect).
    plant : VirtualPlant or None
        The embedded plant (``interface = "embedded"``), else None.
    channel : str or int
        The channel actually used (private for ``embedded``).
    """

    config: LinkConfig
    bus_factory: Callable[[], can.BusABC | UdpReceiver]
    plant: VirtualPlant | None
    channel: str | int

    def make_ring(self) -> RingBuffer:
        """A ring buffer of ``ring_capacity_s`` seconds."""
        return RingBuffer(self.config.capacity_rows)

    def make_acquisition(self, ring: RingBuffer) -> Acquisition:
        """An :class:`Acquisition` wired to this link with the config's timing and protocol."""
        cfg = self.config
        return Acquisition(
            self.bus_factory,
            ring,
            fs_hz=cfg.fs_hz,
            stale_after_s=cfg.stale_after_s,
            receive_timeout_s=cfg.receive_timeout_s,
            # a UDP socket has no connection to lose: reopening it only risks a datagram
            reconnect_after_stale_s=0.0 if cfg.interface == "udp" else cfg.reconnect_after_stale_s,
            backoff_min_s=cfg.backoff_min_s,
            backoff_max_s=cfg.backoff_max_s,
            protocol=link_protocol(cfg),
            rate_tolerance_percent=cfg.rate_tolerance_percent,
        )


def link_protocol(cfg: LinkConfig) -> MappedProtocol | UdpLayout:
    """What the link speaks: the ``[link.udp]`` layout for ``udp``, else the CAN mapping."""
    if cfg.interface == "udp":
        return compile_layout(cfg.udp)
    return protocol_from_config(cfg.protocol)


def bus_factory(
    cfg: LinkConfig, channel: str | int | None = None
) -> Callable[[], can.BusABC | UdpReceiver]:
    """A function opening the bus ``cfg`` describes (``channel`` overrides the config's)."""
    chan = cfg.channel if channel is None else channel
    if cfg.interface == "udp":
        return lambda: _open_udp(cfg)
    if cfg.interface in ("virtual", "embedded"):
        return lambda: can.Bus(interface="virtual", channel=chan, rx_queue_size=cfg.rx_queue_frames)
    if cfg.interface == "socketcand":
        return lambda: _open_socketcand(cfg, str(chan))
    kwargs = dict(cfg.options)
    if cfg.interface not in _NO_BITRATE:
        kwargs.setdefault("bitrate", cfg.bitrate)
    return lambda: can.Bus(interface=cfg.interface, channel=chan, **kwargs)


def _open_udp(cfg: LinkConfig) -> UdpReceiver:
    udp = cfg.udp
    if udp.bind_host not in _LOOPBACK:
        logging.getLogger(__name__).warning(
            "listening for UDP samples on %s:%d, beyond loopback: any host that reaches it "
            "can send samples; bind the interface facing the target only",
            udp.bind_host,
            udp.port,
        )
    try:
        return UdpReceiver(
            udp.bind_host,
            udp.port,
            compile_layout(udp).datagram_bytes,
            udp.receive_buffer_bytes,
        )
    except OSError as exc:
        raise LinkError(
            f"cannot listen for UDP on {udp.bind_host}:{udp.port} ({exc}); fix [link.udp] "
            "bind_host/port or stop what holds the port"
        ) from exc


def _open_socketcand(cfg: LinkConfig, channel: str) -> can.BusABC:
    """rtsid's socketcand client: the handshake bounded by ``_HANDSHAKE_TIMEOUT_S`` (a
    missing or mute server fails fast instead of hanging the caller), frames read in
    batches (:class:`~rtsid.link.socketcand.SocketcandBus`); or python-can's
    (``socketcand_client = "python-can"``), after the same bounded handshake."""
    if cfg.socketcand_client == "python-can":
        # python-can's client retries connect() for 10 s and then waits for the greeting
        # without a timeout: rtsid's client greets it first (bounded), then python-can's
        # connects; python-can's logs a warning for each read that ends inside a frame
        SocketcandBus(channel, cfg.host, cfg.port, timeout_s=_HANDSHAKE_TIMEOUT_S).shutdown()
        logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)
        return can.Bus(
            interface="socketcand",
            host=cfg.host,
            port=cfg.port,
            channel=channel,
            tcp_tune=cfg.tcp_tune,
            **dict(cfg.options),
        )
    return SocketcandBus(
        channel,
        cfg.host,
        cfg.port,
        tcp_tune=cfg.tcp_tune,
        timeout_s=_HANDSHAKE_TIMEOUT_S,
        **dict(cfg.options),
    )


@contextlib.contextmanager
def open_link(
    link_cfg: LinkConfig, plant_cfg: PlantConfig | None = None, *, start_plant: bool = True
) -> Iterator[LinkHandle]:
    """Open the link; for ``embedded`` also run the virtual plant until the block exits.

    Parameters
    ----------
    link_cfg : LinkConfig
        ``[link]``.
    plant_cfg : PlantConfig, optional
        ``[plant]`` (only used by ``embedded``; default settings when omitted).
    start_plant : bool
        Start the embedded plant at once (False: call ``handle.plant.start()`` after the
        acquisition is up, so that no sample is sent before anybody listens).

    Yields
    ------
    LinkHandle
    """
    if link_cfg.interface == "udp" and link_cfg.udp.embedded_plant:
        with _embedded_udp_plant(link_cfg, plant_cfg, start_plant) as handle:
            yield handle
        return
    if link_cfg.interface != "embedded":
        yield LinkHandle(link_cfg, bus_factory(link_cfg), None, link_cfg.channel)
        return
    plant_cfg = _plant_config(link_cfg, plant_cfg)
    channel = f"rtsid-embedded-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    wire = link_protocol(link_cfg)
    # without a counter the sample index comes from the frames' timestamps: the plant stamps
    # each frame with its sample's time and the virtual bus must keep that stamp
    plant_bus = can.Bus(
        interface="virtual",
        channel=channel,
        rx_queue_size=_PLANT_RX_QUEUE,
        preserve_timestamps=wire.uses_timestamps,
    )
    try:
        plant = VirtualPlant(plant_cfg, plant_bus, wire=wire)
    except BaseException:
        plant_bus.shutdown()
        raise
    try:
        if start_plant:
            plant.start()
        yield LinkHandle(link_cfg, bus_factory(link_cfg, channel), plant, channel)
    finally:
        plant.stop()
        plant_bus.shutdown()


def _plant_config(link_cfg: LinkConfig, plant_cfg: PlantConfig | None) -> PlantConfig:
    plant_cfg = plant_cfg or PlantConfig(fs_hz=link_cfg.fs_hz)
    if plant_cfg.fs_hz != link_cfg.fs_hz:
        same = f"link.fs_hz = {link_cfg.fs_hz} (the same rate)"
        raise invalid("plant.fs_hz", plant_cfg.fs_hz, same)
    return plant_cfg


@contextlib.contextmanager
def _embedded_udp_plant(
    link_cfg: LinkConfig, plant_cfg: PlantConfig | None, start_plant: bool
) -> Iterator[LinkHandle]:
    """``interface = "udp"`` with ``[link.udp] embedded_plant``: the virtual plant sends the
    datagrams to the receiver's port on loopback (port 0: a free port, chosen here)."""
    plant_cfg = _plant_config(link_cfg, plant_cfg)
    udp = link_cfg.udp
    if udp.port == 0:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind((udp.bind_host, 0))
            port = int(probe.getsockname()[1])
        link_cfg = dataclasses.replace(link_cfg, udp=dataclasses.replace(udp, port=port))
    target = "::1" if ":" in link_cfg.udp.bind_host else "127.0.0.1"
    sender = UdpSender(target, link_cfg.udp.port)
    try:
        plant = VirtualPlant(plant_cfg, sender, wire=compile_layout(link_cfg.udp))
    except BaseException:
        sender.close()
        raise
    try:
        if start_plant:
            plant.start()
        yield LinkHandle(link_cfg, bus_factory(link_cfg), plant, link_cfg.channel)
    finally:
        plant.stop()
        sender.close()
