"""``rtsid query [KEY]``: the latest estimate of every daemon, or their recent history.

Without a range: one query on ``KEY/estimate`` (each daemon answers its newest estimate; what
a late-joining controller does first). With ``--session``: one query on ``KEY/session`` (each
daemon's subject, session and condition, and the sample they hold from). With ``--since``
or ``--from``/``--to``: one query on ``KEY/history`` (see :mod:`rtsid.io.history` for the
parameters). Messages go to stdout as JSON lines, oldest first; a summary per daemon and
channel (what it holds, where its history starts) goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

from rtsid.commands.common import add_zenoh_reader, connect_endpoints
from rtsid.errors import ConfigError, ServiceError
from rtsid.io.history import QueryError, parse_duration_s
from rtsid.io.validate import check_replies, error_reply_text, printable

if TYPE_CHECKING:
    from rtsid.io.zenoh_link import QueryAnswer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "key", nargs="?", default="rtsid/*/*", help="rtsid/<robot>/<joint> (default rtsid/*/*)"
    )
    add_zenoh_reader(parser, "a router's or a daemon's endpoint")
    parser.add_argument("--since", metavar="DURATION", help="history of the last 60s, 5m, …")
    parser.add_argument("--from", dest="from_ns", type=int, metavar="NS", help="UNIX ns")
    parser.add_argument("--to", dest="to_ns", type=int, metavar="NS", help="UNIX ns")
    parser.add_argument(
        "--kind", metavar="K[,K]", help="channels of the history (default: all held)"
    )
    parser.add_argument(
        "--session",
        action="store_true",
        help="each daemon's session instead (subject, session, condition and the sample it "
        "holds from: the KEY/session queryable)",
    )
    parser.add_argument("--timeout", type=float, default=5.0, help="wait at most S s (5)")


def selector(args: argparse.Namespace) -> str:
    """The zenoh selector the arguments ask for (``KEY/estimate`` or ``KEY/history?…``)."""
    from rtsid.io.zenoh_link import user_key_expr

    key = user_key_expr(args.key)
    if getattr(args, "session", False):
        if args.since is not None or args.from_ns is not None or args.to_ns is not None:
            raise ConfigError("--session asks for the current session; drop --since/--from/--to")
        return f"{key}/session"
    params = []
    if args.since is not None:
        try:
            params.append(f"since={parse_duration_s(args.since):g}s")
        except QueryError as exc:
            raise ConfigError(f"--since: {exc}") from None
    if args.from_ns is not None:
        params.append(f"from={args.from_ns}")
    if args.to_ns is not None:
        params.append(f"to={args.to_ns}")
    if args.kind:
        params.append(f"kind={args.kind}")
    if not params:
        return f"{key}/estimate"
    return f"{key}/history?" + ";".join(params)


def run(args: argparse.Namespace) -> int:
    import zenoh

    from rtsid.io.zenoh_link import query, subscriber_config

    if args.since is not None and args.from_ns is not None:
        raise ConfigError("give --since or --from, not both")
    if not args.timeout > 0:
        raise ConfigError(f"--timeout {args.timeout} is not accepted; expected seconds > 0")
    connect = connect_endpoints(args)
    wanted = selector(args)
    try:
        session = zenoh.open(subscriber_config(connect, args.mode))
    except zenoh.ZError as exc:
        raise ServiceError(
            f"cannot reach {', '.join(connect)}: {exc}; is the router (or daemon) running there?"
        ) from None
    with session:
        try:
            answer = query(session, wanted, timeout_s=args.timeout)
        except zenoh.ZError as exc:
            raise ConfigError(f"zenoh refused the query {wanted!r}: {exc}") from None
    return _report(answer, wanted, f"within {args.timeout:g} s via {', '.join(connect)}")


def _report(answer: QueryAnswer, wanted: str, where: str) -> int:
    """Print the checked messages (stdout, JSON lines, oldest first) and the history summary,
    error replies and rejected replies (stderr, one printable line each); the exit code."""
    for error in answer.errors:
        print(f"rtsid query: error reply: {error_reply_text(error)}", file=sys.stderr)
    checked = check_replies(answer.replies)
    for part in checked.parts:
        if part["part"] == 0:
            print(_summary(part), file=sys.stderr)
    for why in checked.rejected[:5]:
        print(f"rtsid query: rejected a malformed reply: {why}", file=sys.stderr)
    if checked.rejected:
        print(
            f"rtsid query: rejected {len(checked.rejected)} malformed replies or messages "
            "(not printed); a peer that is not an rtsid daemon may answer on this key",
            file=sys.stderr,
        )
    for _, _, message in checked.messages:
        sys.stdout.write(json.dumps(message, separators=(",", ":"), allow_nan=False) + "\n")
    sys.stdout.flush()
    if not answer.replies and not answer.errors:
        print(
            f"rtsid query: no daemon answered {wanted} {where}; check the key and that the "
            "daemons are connected",
            file=sys.stderr,
        )
        return 1
    return 1 if answer.errors or (not checked.messages and not checked.parts) else 0


def _summary(part: dict[str, Any]) -> str:
    held = part["held_from_ns"]
    where = "nothing held" if held is None else f"held from {held} ns"
    text = f"rtsid query: {part['robot']}/{part['joint']} {part['kind']}: {where}"
    return text + (f"; {printable(part['note'])}" if part["note"] else "; the whole range is held")
