"""``rtsid plant``: run the virtual ankle robot behind a socketcand server on loopback.

A daemon (or ``cantools monitor``/python-can) then connects with python-can's
``socketcand`` interface to ``127.0.0.1:PORT``, channel ``can0``, exactly as to a real
socketcand host. Runs until SIGINT/SIGTERM (or ``--duration``); prints one line with the
address when ready and one line of counters (JSON) at the end. The plant speaks the config's
``[link.protocol]``; with ``[link] interface = "udp"`` it sends the ``[link.udp]``
datagrams to ``--host``:``[link.udp] port`` instead.
"""

from __future__ import annotations

import argparse

from rtsid.commands.common import add_duration, add_fs, deprecated_alias
from rtsid.link.serve import PlantServerOptions, serve_plant

PLANT_MODES = ("sim", "player", "torque_multisine")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="TOML file with [plant] and [link] (its [link.protocol]; interface = 'udp': "
        "send [link.udp] datagrams)",
    )
    parser.add_argument("--host", default="127.0.0.1", help="loopback address (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=29536, help="TCP port, 0 = a free one")
    parser.add_argument("--channel", default="can0", help="bus name clients open (default can0)")
    parser.add_argument("--plant-mode", choices=PLANT_MODES, help="override [plant] mode")
    # --mode is the zenoh session's in every other command
    deprecated_alias(parser, "--mode", "--plant-mode", "plant_mode", choices=PLANT_MODES)
    parser.add_argument("--file", metavar="NPZ", help="recording for player mode")
    add_fs(parser, "override [plant] fs_hz (frame rate)")
    parser.add_argument("--fast", action="store_true", help="as fast as the client reads")
    add_duration(parser, "stop after S seconds (default: run until stopped)")


def run(args: argparse.Namespace) -> int:
    options = PlantServerOptions(
        config=args.config,
        host=args.host,
        port=args.port,
        channel=args.channel,
        mode=args.plant_mode,
        player_file=args.file,
        fs_hz=args.fs,
        fast=args.fast,
        duration_s=args.duration or 0.0,
    )
    return serve_plant(options)
