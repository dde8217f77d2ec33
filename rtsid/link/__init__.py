"""The hardware link: CAN protocol (any DBC mapped by ``[link.protocol]``; the ankle's built
in), a UDP source, ring buffer, acquisition thread, virtual plant and socketcand server.

Data path: ``bus (python-can) → Acquisition thread → RingBuffer → readers``. The virtual
plant sits behind the same boundary (an in-process ``virtual`` bus, or a socketcand server
in another process), so the daemon cannot tell it from the robot.
"""

from rtsid.link.acquisition import Acquisition, LinkCounters
from rtsid.link.config import (
    FaultConfig,
    LinkConfig,
    PlantConfig,
    ProtocolConfig,
    StiffnessConfig,
    UdpConfig,
    link_configs_from_mapping,
    load_link_configs,
)
from rtsid.link.open import LinkHandle, bus_factory, open_link
from rtsid.link.plant import VirtualPlant
from rtsid.link.protocol import Command
from rtsid.link.ring import RingBuffer, Snapshot
from rtsid.link.socketcand import SocketcandServer

__all__ = [
    "Acquisition",
    "Command",
    "FaultConfig",
    "LinkConfig",
    "LinkCounters",
    "LinkHandle",
    "PlantConfig",
    "ProtocolConfig",
    "RingBuffer",
    "Snapshot",
    "SocketcandServer",
    "StiffnessConfig",
    "UdpConfig",
    "VirtualPlant",
    "bus_factory",
    "link_configs_from_mapping",
    "load_link_configs",
    "open_link",
]
