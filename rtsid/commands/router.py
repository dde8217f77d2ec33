"""``rtsid router``: a zenoh router (eclipse-zenoh's router mode) for a lab of daemons."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from rtsid.commands.common import add_duration
from rtsid.runtime.router import load_router_config, run_router


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config", metavar="TOML", help="file with a [router] section (listen, config_file)"
    )
    parser.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="endpoint to listen on, repeatable (default tcp/127.0.0.1:7447, loopback only)",
    )
    add_duration(parser, "stop after S seconds")


def run(args: argparse.Namespace) -> int:
    cfg = load_router_config(args.config, tuple(args.listen or ()))
    stop = threading.Event()
    previous = {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        seen = run_router(
            cfg,
            stop,
            on_event=lambda line: print(f"rtsid router: {line}", flush=True),
            duration_s=args.duration,
        )
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(f"rtsid router: stopped ({seen} daemons seen)", file=sys.stderr)
    return 0
