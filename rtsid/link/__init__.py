"""The hardware link: CAN protocol (any DBC mapped by ``[link.protocol]``; the ankle's built
in), a UDP source, ring buffer, acquisition thread, virtual plant and socketcand server.

Data path: ``bus (python-can) → Acquisition thread → RingBuffer → readers``. The virtual
plant sits behind the same boundary (an in-process ``virtual`` bus, or a socketcand server
in another process), so the daemon cannot tell it from the robot.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rtsid.link.acquisition import Acquisition
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
    from rtsid.link.counters import LinkCounters
    from rtsid.link.open import LinkHandle, bus_factory, open_link
    from rtsid.link.plant import VirtualPlant
    from rtsid.link.protocol import Command
    from rtsid.link.ring import RingBuffer, Snapshot
    from rtsid.link.socketcand import SocketcandServer

#: Where each name lives: imported on first use (PEP 562), so that a reader of recordings
#: that needs one small piece (``rtsid.io.messages`` takes ``LinkCounters``) does not import
#: the virtual plant and its numerics (scipy, ~1 s).
_SUBMODULE = {
    "Acquisition": "rtsid.link.acquisition",
    "LinkCounters": "rtsid.link.counters",
    "FaultConfig": "rtsid.link.config",
    "LinkConfig": "rtsid.link.config",
    "PlantConfig": "rtsid.link.config",
    "ProtocolConfig": "rtsid.link.config",
    "StiffnessConfig": "rtsid.link.config",
    "UdpConfig": "rtsid.link.config",
    "link_configs_from_mapping": "rtsid.link.config",
    "load_link_configs": "rtsid.link.config",
    "LinkHandle": "rtsid.link.open",
    "bus_factory": "rtsid.link.open",
    "open_link": "rtsid.link.open",
    "VirtualPlant": "rtsid.link.plant",
    "Command": "rtsid.link.protocol",
    "RingBuffer": "rtsid.link.ring",
    "Snapshot": "rtsid.link.ring",
    "SocketcandServer": "rtsid.link.socketcand",
}


def __getattr__(name: str) -> Any:
    module = _SUBMODULE.get(name)
    if module is None:
        raise AttributeError(f"module 'rtsid.link' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


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
