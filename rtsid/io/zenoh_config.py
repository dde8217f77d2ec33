"""The ``[zenoh]`` config section (:class:`ZenohConfig`): how the daemon publishes.

Apart from :mod:`rtsid.io.zenoh_link` (the publisher, its queryables and the history ring,
which import it back) so that what only reads a configuration — a replay, each spawned
process of ``rtsid replay DIR --jobs N`` — does not compile and import the live transport.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from rtsid.config import invalid, require_choice, require_range, section_from_mapping

__all__ = ["ENDPOINT_PATTERN", "ZenohConfig"]

_CHUNK = re.compile(r"^[A-Za-z0-9_.\-]+$")
_PREFIX = re.compile(r"^[A-Za-z0-9_.\-]+(/[A-Za-z0-9_.\-]+)*$")
#: A zenoh endpoint, ``protocol/address`` (``tcp/127.0.0.1:7447``).
ENDPOINT_PATTERN = re.compile(r"^[a-z0-9]+/.+$")


@dataclass(frozen=True)
class ZenohConfig:
    """The ``[zenoh]`` config section.

    Attributes
    ----------
    enabled : bool
        False: no session at all (publishing calls are no-ops, state ``disabled``).
    mode : str
        ``"peer"`` (default) or ``"client"`` (connect to a router / peer given in ``connect``).
    listen : tuple of str
        Endpoints to listen on, e.g. ``"tcp/127.0.0.1:7447"`` (peer mode only: a client
        does not listen, and the default is ignored in client mode).
    connect : tuple of str
        Endpoints to connect to (a ``zenohd`` router for a lab).
    multicast_scouting, gossip_scouting : bool
        Zenoh discovery; off by default (explicit endpoints only, never multicast here).
    robot, joint : str
        Names in every key expression (letters, digits, ``_ . -``).
    key_prefix : str
        First key chunk(s), default ``"rtsid"``.
    publish_samples : bool
        Also publish batched raw samples (for live plots).
    config_file : str
        A zenoh json5 config file that replaces mode/listen/connect/scouting entirely (leave
        those keys at their defaults when using it). Empty: not used.
    retry_interval_s : float
        While the session is down, try to open it again this often, s.
    history_s : float
        Estimates and status kept in memory for the ``history`` queryable, s (0: no
        history; the ``estimate`` and ``status`` queryables still answer the latest).
        About 0.11 kB per estimate once compressed
        (:meth:`rtsid.io.zenoh_link.ZenohPublisher.compact_history`): 10 min at 250 Hz (a
        4 ms hop) is ≈ 16 MiB, at 50 Hz ≈ 3.5 MiB.
    """

    enabled: bool = True
    mode: str = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    gossip_scouting: bool = False
    robot: str = "robot"
    joint: str = "ankle"
    key_prefix: str = "rtsid"
    publish_samples: bool = False
    config_file: str = ""
    retry_interval_s: float = 5.0
    history_s: float = 600.0

    def __post_init__(self) -> None:
        require_choice("mode", self.mode, ("peer", "client"))
        require_range("history_s", self.history_s, 0.0, 86400.0)
        for name in ("robot", "joint"):
            value = getattr(self, name)
            if not _CHUNK.match(value):
                raise invalid(name, value, "a non-empty name of letters, digits, '_', '.', '-'")
        if not _PREFIX.match(self.key_prefix):
            raise invalid(
                "key_prefix",
                self.key_prefix,
                "key chunks of letters, digits, '_', '.', '-' separated by '/' (no wildcards)",
            )
        for name in ("listen", "connect"):
            for endpoint in getattr(self, name):
                if not ENDPOINT_PATTERN.match(endpoint):
                    raise invalid(name, endpoint, "endpoints like 'tcp/127.0.0.1:7447'")
        if self.mode == "client" and not self.connect and not self.config_file:
            raise invalid("connect", list(self.connect), "at least one endpoint in client mode")
        if self.mode == "client" and self.listen not in ((), ZenohConfig.listen):
            raise invalid(
                "listen",
                list(self.listen),
                "no endpoints in client mode (a client only connects, to the router in "
                "zenoh.connect); remove zenoh.listen or use mode = 'peer'",
            )
        require_range("retry_interval_s", self.retry_interval_s, 0.0, 3600.0, low_inclusive=False)
        if self.config_file:
            defaults = ZenohConfig()
            changed = [
                k
                for k in ("mode", "listen", "connect", "multicast_scouting", "gossip_scouting")
                if getattr(self, k) != getattr(defaults, k)
            ]
            if changed:
                raise invalid(
                    changed[0],
                    getattr(self, changed[0]),
                    "its default when config_file is set (the file replaces mode, listen, "
                    "connect and scouting); put it in the json5 file instead",
                )

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any] | None) -> ZenohConfig:
        """Build from the ``[zenoh]`` TOML table (unknown keys and bad values rejected)."""
        return section_from_mapping(cls, mapping, "zenoh")
