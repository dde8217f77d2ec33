"""``rtsid watch [KEY]``: live K, B, I, VAF, latency and status from running daemons."""

from __future__ import annotations

import argparse

from rtsid.commands.common import add_zenoh_reader, connect_endpoints
from rtsid.errors import ConfigError
from rtsid.io.history import QueryError, parse_duration_s


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "key",
        nargs="?",
        default="rtsid/*/*",
        help="key expression of the daemon(s): rtsid/<robot>/<joint> (default: rtsid/*/*)",
    )
    add_zenoh_reader(parser, "zenoh endpoint of the daemon or the lab's router")
    parser.add_argument("--count", type=int, default=None, help="exit after N estimates")
    parser.add_argument("--timeout", type=float, default=None, help="exit after S seconds")
    parser.add_argument(
        "--plain", action="store_true", help="one line per estimate even on a terminal"
    )
    parser.add_argument(
        "--since",
        metavar="DURATION",
        help="first show the history the daemons hold for the last 60s, 5m, … (a zenoh query)",
    )
    parser.add_argument(
        "--web",
        nargs="?",
        const=8088,
        type=int,
        metavar="PORT",
        help="serve a live page (K, B, I with 95 %% bands, VAF, withheld windows, counters) "
        "on http://HOST:PORT/ instead of the table (default port 8088)",
    )
    parser.add_argument(
        "--host",
        default="127.0.0.1",
        help="address the --web page binds to (default 127.0.0.1: this machine only; a lab "
        "opens it explicitly, e.g. 0.0.0.0)",
    )


def run(args: argparse.Namespace) -> int:
    from rtsid.io.watch import watch

    if args.count is not None and args.count < 1:
        raise ConfigError(f"--count {args.count} is not accepted; expected an integer >= 1")
    if args.timeout is not None and not args.timeout > 0:
        raise ConfigError(f"--timeout {args.timeout} is not accepted; expected seconds > 0")
    since_s = None
    if args.since is not None:
        try:
            since_s = parse_duration_s(args.since, "--since")
        except QueryError as exc:
            raise ConfigError(str(exc)) from None
    from rtsid.io.zenoh_link import user_key_expr

    key = user_key_expr(args.key)
    connect = connect_endpoints(args)
    if args.web is not None:
        from rtsid.io.web.server import serve_web

        return serve_web(
            key,
            connect,
            mode=args.mode,
            host=args.host,
            port=args.web,
            timeout_s=args.timeout,
        )
    return watch(
        key,
        connect,
        mode=args.mode,
        count=args.count,
        timeout_s=args.timeout,
        live=False if args.plain else None,
        since_s=since_s,
    )
