"""``rtsid watch [KEY]``: live K, B, I, VAF, latency and status from running daemons."""

from __future__ import annotations

import argparse

from rtsid.errors import ConfigError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "key",
        nargs="?",
        default="rtsid/*/*",
        help="key expression of the daemon(s): rtsid/<robot>/<joint> (default: rtsid/*/*)",
    )
    parser.add_argument(
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="zenoh endpoint of the daemon (repeatable; default: tcp/127.0.0.1:7447)",
    )
    parser.add_argument(
        "--mode",
        choices=("peer", "client"),
        default="peer",
        help="peer (default) waits for a daemon that starts later; client needs it up now",
    )
    parser.add_argument("--count", type=int, default=None, help="exit after N estimates")
    parser.add_argument("--timeout", type=float, default=None, help="exit after S seconds")
    parser.add_argument(
        "--plain", action="store_true", help="one line per estimate even on a terminal"
    )


def run(args: argparse.Namespace) -> int:
    from rtsid.io.watch import watch

    if args.count is not None and args.count < 1:
        raise ConfigError(f"--count {args.count} is not accepted; expected an integer >= 1")
    if args.timeout is not None and not args.timeout > 0:
        raise ConfigError(f"--timeout {args.timeout} is not accepted; expected seconds > 0")
    connect = tuple(args.connect or ["tcp/127.0.0.1:7447"])
    return watch(
        args.key,
        connect,
        mode=args.mode,
        count=args.count,
        timeout_s=args.timeout,
        live=False if args.plain else None,
    )
