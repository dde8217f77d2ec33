"""Run the virtual plant behind a socketcand server until a signal (``rtsid plant``).

The plant speaks the config's ``[link.protocol]`` (the built-in ankle protocol by default).
With ``[link] interface = "udp"`` it sends the ``[link.udp]`` datagrams to
``--host``:``[link.udp] port`` instead (a plant UDP sender for a daemon listening there).
"""

from __future__ import annotations

import dataclasses
import json
import signal
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rtsid.config import invalid, load_toml
from rtsid.errors import ConfigError
from rtsid.link.config import (
    LinkConfig,
    PlantConfig,
    link_config_from_mapping,
    plant_config_from_mapping,
)
from rtsid.link.open import link_protocol
from rtsid.link.plant import VirtualPlant
from rtsid.link.socketcand import SocketcandServer
from rtsid.link.udp import UdpSender

__all__ = ["PlantServerOptions", "link_config_for", "plant_config_for", "serve_plant"]

_STOP_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class PlantServerOptions:
    """Command-line choices of ``rtsid plant`` (None: keep the config file's value)."""

    config: str | None = None
    host: str = "127.0.0.1"
    port: int = 29536
    channel: str = "can0"
    mode: str | None = None
    player_file: str | None = None
    fs_hz: float | None = None
    fast: bool = False
    duration_s: float = 0.0


def plant_config_for(options: PlantServerOptions) -> PlantConfig:
    """The ``[plant]`` section of ``options.config`` with the command-line overrides."""
    if not 0 <= options.port <= 65535:
        raise ConfigError(f"--port {options.port} is not a TCP port; pass 0..65535 (0: a free one)")
    document = load_toml(options.config) if options.config else {}
    base_dir = Path(options.config).resolve().parent if options.config else None
    link_config_for(options)  # the protocol the plant speaks; a bad [link] is said at once
    table = document.get("plant") or {}
    if not isinstance(table, Mapping):
        raise invalid("plant", table, "a table [plant]")
    table = dict(table)
    overrides = {
        "mode": options.mode,
        "player_file": options.player_file,
        "fs_hz": options.fs_hz,
        "realtime": False if options.fast else None,
    }
    table.update({k: v for k, v in overrides.items() if v is not None})
    if options.player_file:  # a path typed on the command line is relative to the cwd
        table["player_file"] = str(Path(options.player_file).resolve())
    if options.player_file and "mode" not in table:
        table["mode"] = "player"
    return plant_config_from_mapping(table, base_dir)


def link_config_for(options: PlantServerOptions) -> LinkConfig:
    """The ``[link]`` section of ``options.config`` (defaults without a config)."""
    document = load_toml(options.config) if options.config else {}
    base_dir = Path(options.config).resolve().parent if options.config else None
    link_table = document.get("link")
    if link_table is not None and not isinstance(link_table, Mapping):
        raise invalid("link", link_table, "a table [link]")
    return link_config_from_mapping(link_table, base_dir)


def serve_plant(options: PlantServerOptions) -> int:
    """Serve until SIGINT/SIGTERM or ``duration_s``; bounded shutdown. Returns an exit code."""
    cfg = plant_config_for(options)
    link = link_config_for(options)
    stop = threading.Event()
    previous = {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        if link.interface == "udp":
            sender = UdpSender(options.host, link.udp.port)
            try:
                plant = VirtualPlant(cfg, sender, wire=link_protocol(link))
                print(
                    f"rtsid plant: sending UDP datagrams to {options.host}:{link.udp.port} "
                    f"({cfg.mode}, {cfg.fs_hz:g} Hz)",
                    flush=True,
                )
                return _run_plant(plant, options, stop, {})
            finally:
                sender.close()
        with SocketcandServer(options.host, options.port, options.channel) as server:
            plant = VirtualPlant(cfg, server, wire=link_protocol(link))
            print(
                f"rtsid plant: socketcand server on {server.host}:{server.port} channel "
                f"{options.channel} ({cfg.mode}, {cfg.fs_hz:g} Hz)",
                flush=True,
            )
            return _run_plant(plant, options, stop, server)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _run_plant(
    plant: VirtualPlant, options: PlantServerOptions, stop: threading.Event, server: Any
) -> int:
    """Run the plant until a signal, ``duration_s`` or its end; print the JSON report."""
    started = time.monotonic()
    with plant:
        deadline = time.monotonic() + options.duration_s if options.duration_s else None
        while not stop.is_set() and not plant.done.is_set():
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                break
            stop.wait(0.2 if remaining is None else min(0.2, remaining))
        plant.stop(_STOP_TIMEOUT_S)
    report = {
        "elapsed_s": time.monotonic() - started,
        "plant": dataclasses.asdict(plant.counters()),
        "server": dataclasses.asdict(server.counters()) if server else {},
    }
    print(json.dumps(report), flush=True)
    if plant.error is not None:
        print(f"rtsid plant: error: {plant.error}", file=sys.stderr)
        return 1
    return 0
